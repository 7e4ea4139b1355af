"""A run killed at any moment and resumed ends exactly as if it had never stopped; files load without running code."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from torchrl_mbe.app import ConfigError, train
from torchrl_mbe.app.checkpoints import load_safely
from torchrl_mbe.rundir import BEST_POLICY, CHECKPOINT, SUMMARY

HERE = Path(__file__).parent
SHORT_DEFAULT_RUN = (
    "progress_bar=false",
    "logger=csv",
    "logger.log_every_updates=40",
    "env.num_envs=4",
    "collector.frames_per_batch=32",
    "algo.num_cells=[64,64]",
    "train.max_frames=2400",
    "train.stop_when_solved=false",
    "train.checkpoint_every_frames=512",
    "eval.every_frames=512",
    "eval.episodes=2",
    "eval.final_episodes=2",
    "algo.learning_starts=256",
    "dynamics.learning_starts=128",
)
"""The default MountainCar run (torch-batched envs, 3-step returns, gaussian planning), smaller: 4 envs, 2,400 frames, a checkpoint every 512."""
TIMING_COLUMNS = {"wall_time_s", "frames_per_s"}


def run_train(run_dir: Path, *args: str, kill: tuple[str, int] | None = None) -> subprocess.CompletedProcess:
    script = [str(HERE / "killed_run.py"), kill[0], str(kill[1])] if kill else [str(HERE.parents[1] / "train.py")]
    return subprocess.run(
        [sys.executable, *script, *SHORT_DEFAULT_RUN, f"hydra.run.dir={run_dir}", *args],
        env={**os.environ, "WANDB_MODE": "disabled"},
        capture_output=True,
        text=True,
        timeout=600,
    )


def run_files(run_dir: Path) -> dict:
    """Every table (timing columns aside), the summary (timings aside) and the final weights of a run."""
    tables = {}
    for table in ("episodes", "evaluations", "updates"):
        with (run_dir / f"{table}.csv").open() as handle:
            tables[table] = [
                {k: v for k, v in row.items() if k not in TIMING_COLUMNS} for row in csv.DictReader(handle)
            ]
    summary = {
        k: v
        for k, v in json.loads((run_dir / SUMMARY).read_text()).items()
        if "wall_time" not in k and k not in ("frames_per_s", "record")  # record: the command differs by resume=true
    }
    return {**tables, "summary": summary, "weights": load_safely(run_dir / CHECKPOINT)["agent"]["policy"]}


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory) -> dict:
    run_dir = tmp_path_factory.mktemp("uninterrupted")
    result = run_train(run_dir)
    assert result.returncode == 0, result.stderr
    return run_files(run_dir)


@pytest.mark.parametrize(
    "kill",
    [("frames", 600), ("frames", 1300), ("checkpoint-write", 1536)],
    ids=["early", "mid-run", "checkpoint-write"],
)
def test_a_killed_and_resumed_run_ends_exactly_as_the_uninterrupted_one(tmp_path, uninterrupted, kill):
    killed = run_train(tmp_path, kill=kill)
    assert killed.returncode == -9, killed.stderr  # SIGKILL: nothing could clean up
    if kill[0] == "checkpoint-write":
        assert (tmp_path / (CHECKPOINT + ".partial")).exists()
    assert load_safely(tmp_path / CHECKPOINT)["frames"] < kill[1]
    resumed = run_train(tmp_path, "resume=true")
    assert resumed.returncode == 0, resumed.stderr
    again = run_files(tmp_path)
    assert (
        again["summary"]["episodes"] >= 8 and len(again["evaluations"]) == 5
    )  # episodes ended on both sides of the kill
    for part in ("episodes", "evaluations", "updates", "summary"):
        assert again[part] == uninterrupted[part], part
    torch.testing.assert_close(again["weights"], uninterrupted["weights"], rtol=0, atol=0)  # bit for bit


@pytest.mark.parametrize("exploration", ["egreedy", "rnd"])
def test_a_run_whose_policy_draws_random_numbers_resumes_on_the_same_random_stream(
    exploration, tmp_path, compose_config
):
    # The collector checks its policy once when built; e-greedy's check draws from torch's generator.
    overrides = (f"exploration={exploration}", "env.num_envs=2", "eval.final_episodes=0", "algo.num_cells=[16,16]")
    train(compose_config(*overrides), tmp_path / "whole")
    train(compose_config(*overrides, "train.max_frames=160"), tmp_path / "resumed")
    train(compose_config(*overrides, "resume=true"), tmp_path / "resumed")
    agents = [load_safely(tmp_path / run / CHECKPOINT)["agent"] for run in ("whole", "resumed")]
    torch.testing.assert_close(agents[1], agents[0], rtol=0, atol=0)


class Payload:
    """Pickles as a call that leaves a file behind: what a crafted checkpoint or shared policy could do."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (Path.write_text, (self.marker, "code ran"))


@pytest.mark.parametrize("file", [CHECKPOINT, BEST_POLICY])
def test_a_file_that_carries_a_pickled_callable_is_refused_and_never_runs(tmp_path, compose_config, file):
    run_dir, marker = tmp_path / "run", tmp_path / "marker"
    train(
        compose_config("train.max_frames=120", "eval.final_episodes=0", "eval.episodes=1", "eval.every_frames=100"),
        run_dir,
    )
    saved = load_safely(run_dir / file)
    saved["payload"] = Payload(marker)
    torch.save(saved, run_dir / file)
    assert torch.load(run_dir / file, weights_only=False) and marker.exists()  # the file does carry code
    marker.unlink()
    with pytest.raises(ConfigError, match=rf"Refusing .*{file}: it holds \S+, which a weights-only load does not run"):
        load_safely(run_dir / file)
    if file == CHECKPOINT:
        with pytest.raises(ConfigError, match="Refusing"):
            train(compose_config("train.max_frames=240", "eval.final_episodes=0", "resume=true"), run_dir)
    assert not marker.exists()


def test_checkpoints_and_best_policies_hold_only_what_a_weights_only_load_reads(tmp_path, compose_config):
    train(
        compose_config(
            "buffer=prioritized", "exploration=rnd", "algo.n_steps=3", "eval.episodes=1", "eval.every_frames=160"
        ),
        tmp_path,
    )
    for file in (CHECKPOINT, BEST_POLICY):
        assert isinstance(torch.load(tmp_path / file, weights_only=True), dict)
