from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir

import torchrl_mbe.training as training
from torchrl_mbe.config import ConfigError
from torchrl_mbe.training import CHECKPOINT_NAME, train

REPO = Path(__file__).resolve().parents[1]
QUICK = [
    "logger=csv",
    "progress_bar=false",
    "train.episodes=50",
    "train.max_frames=300",
    "algo.learning_starts=100",
    "eval.episodes=0",
    "eval.final_episodes=1",
]


def compose_config(*overrides: str):
    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        return compose("config", overrides=[*QUICK, *overrides])


def read_table(run_dir: Path, table: str) -> list[dict]:
    with (run_dir / f"{table}.csv").open() as handle:
        return list(csv.DictReader(handle))


@pytest.mark.parametrize("exploration", ["gaussian", "kernel", "egreedy", "none"])
def test_every_explorer_trains_on_mountaincar_and_writes_its_run(tmp_path, exploration):
    summary = train(compose_config(f"exploration={exploration}"), tmp_path)
    assert summary["frames"] >= 300 and summary["q_updates"] >= 50  # 0.25 updates per frame after 100
    assert summary["method"] == f"dqn+{exploration}"
    assert (summary["dynamics_updates"] > 0) == (exploration in ("gaussian", "kernel"))
    episodes = read_table(tmp_path, "episodes")
    assert [int(row["episode"]) for row in episodes] == list(range(1, summary["episodes"] + 1))
    assert json.loads((tmp_path / "summary.json").read_text()) == summary
    assert (tmp_path / CHECKPOINT_NAME).exists()


@pytest.mark.parametrize("env", ["lunarlander", "acrobot", "cartpole"])
def test_other_supported_envs_train_with_gaussian_exploration(tmp_path, env):
    summary = train(compose_config(f"env={env}"), tmp_path)
    assert summary["frames"] >= 300 and summary["dynamics_updates"] > 0
    assert summary["final_eval_return"] is not None


def test_batched_envs_and_prioritized_replay(tmp_path):
    summary = train(compose_config("env.num_envs=4", "buffer=prioritized", "collector.frames_per_batch=32"), tmp_path)
    assert summary["frames"] >= 300 and summary["q_updates"] > 0


def test_paper_preset_decays_eps_by_0_9995_per_update(tmp_path):
    cfg = compose_config("experiment=paper_mountaincar", "algo.learning_starts=100", "train.max_frames=250")
    assert cfg.algo.num_cells == [48] and cfg.loss.hard_update_interval == 8 and cfg.optim.q_lr == 0.05
    train(cfg, tmp_path)
    last = read_table(tmp_path, "episodes")[-1]
    decayed_steps = int(last["frames"]) - 1 - 100  # eps logged is the one that acted on the last frame
    assert float(last["eps"]) == pytest.approx(0.9995**decayed_steps, abs=2e-5)


def test_same_config_and_seed_give_the_same_returns(tmp_path):
    cfg = compose_config("train.max_frames=600")
    first, second = train(cfg, tmp_path / "a"), train(cfg, tmp_path / "b")
    returns = [[row["return"] for row in read_table(tmp_path / run, "episodes")] for run in "ab"]
    assert returns[0] == returns[1] and len(returns[0]) >= 2
    assert first["final_eval_return"] == second["final_eval_return"]


def test_ctrl_c_saves_and_resume_continues_without_losing_or_repeating_frames(tmp_path, monkeypatch):
    cfg = compose_config("train.max_frames=480", "eval.final_episodes=0")
    calls = {"n": 0}
    original = training.record_episodes

    def press_ctrl_c_at_the_tenth_batch(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 10:
            os.kill(os.getpid(), signal.SIGINT)
        return original(*args, **kwargs)

    monkeypatch.setattr(training, "record_episodes", press_ctrl_c_at_the_tenth_batch)
    with pytest.raises(SystemExit, match="Interrupted at 160 frames"):
        train(cfg, tmp_path)
    monkeypatch.setattr(training, "record_episodes", original)
    checkpoint = torch.load(tmp_path / CHECKPOINT_NAME, weights_only=False)
    assert checkpoint["progress"]["frames"] == 160
    assert len(checkpoint["buffer"]["_storage"]["_storage"]["observation"]) >= 160

    cfg.resume = True
    summary = train(cfg, tmp_path)
    assert summary["frames"] == 480
    final = torch.load(tmp_path / CHECKPOINT_NAME, weights_only=False)
    assert int(final["buffer"]["_storage"]["_len"]) == 480  # every frame stored once
    episodes = [int(row["episode"]) for row in read_table(tmp_path, "episodes")]
    assert episodes == list(range(1, len(episodes) + 1))


@pytest.mark.parametrize(
    "overrides, message",
    [
        (["exploration.window=1"], "exploration.window=1: the novelty window needs at least 2"),
        (["buffer.size=-5"], "buffer.size=-5: expected a positive integer"),
        (["algo.batch_size=0"], "algo.batch_size=0: expected a positive integer"),
        (["env.name=Pendulum-v1"], "Pendulum-v1 has a Box action space"),
        (["env.name=NoSuchEnv-v9"], "Unknown environment 'NoSuchEnv-v9'"),
        (["env=lunarlander", "dynamics=oracle"], "dynamics=oracle exists for MountainCar-v0 only"),
        (["env.num_envs=3"], "must be a multiple of env.num_envs=3"),
    ],
)
def test_bad_config_values_get_one_clear_error(tmp_path, overrides, message):
    with pytest.raises(ConfigError, match=message):
        train(compose_config(*overrides), tmp_path)
    assert not (tmp_path / CHECKPOINT_NAME).exists()


def test_a_finished_run_is_never_overwritten_and_foreign_checkpoints_are_refused(tmp_path):
    train(compose_config("train.max_frames=120", "eval.final_episodes=0"), tmp_path)
    before = (tmp_path / "episodes.csv").read_text()
    with pytest.raises(ConfigError, match="already holds a run. Pass resume=true"):
        train(compose_config("train.max_frames=120"), tmp_path)
    with pytest.raises(ConfigError, match=r"another config; differing keys: algo.batch_size: 256 -> 32$"):
        train(compose_config("resume=true", "algo.batch_size=32"), tmp_path)
    assert (tmp_path / "episodes.csv").read_text() == before
    (tmp_path / CHECKPOINT_NAME).write_bytes(b"not a checkpoint")
    with pytest.raises(ConfigError, match="Cannot read checkpoint"):
        train(compose_config("resume=true"), tmp_path)


def run_app(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "WANDB_MODE": "disabled"}
    return subprocess.run(
        [sys.executable, str(REPO / "train.py"), *args, *QUICK],
        cwd=cwd, env=env, capture_output=True, text=True, timeout=600,
    )


def test_train_py_runs_and_prints_a_summary(tmp_path):
    result = run_app("env=mountaincar", "exploration=gaussian", f"hydra.run.dir={tmp_path}/run", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert '"method": "dqn+gaussian"' in result.stderr + result.stdout
    assert (tmp_path / "run" / "summary.json").exists()
    bad = run_app("exploration.window=1", f"hydra.run.dir={tmp_path}/bad", cwd=tmp_path)
    assert bad.returncode == 1
    assert "Error: exploration.window=1" in bad.stderr and "Traceback" not in bad.stderr


def test_multirun_sweep_writes_one_run_per_job(tmp_path):
    result = run_app("-m", "exploration=gaussian,egreedy", f"hydra.sweep.dir={tmp_path}/sweep", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    methods = sorted(json.loads(p.read_text())["method"] for p in (tmp_path / "sweep").glob("*/summary.json"))
    assert methods == ["dqn+egreedy", "dqn+gaussian"]


def test_wandb_logs_offline_into_the_run_dir(tmp_path, monkeypatch):
    monkeypatch.setenv("WANDB_MODE", "offline")
    train(compose_config("logger=wandb", "train.max_frames=100", "eval.final_episodes=0"), tmp_path)
    assert list((tmp_path / "wandb").glob("offline-run-*"))
