from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import torch
import torchrl

import torchrl_mbe.app.population as population_module
import torchrl_mbe.app.run as run_module
from torchrl_mbe.app import ConfigError, train
from torchrl_mbe.rundir import BEST_POLICY, CHECKPOINT


@pytest.mark.parametrize(
    "exploration",
    ["gaussian", "kernel", "diagonal", "knn", "kde", "counts", "rnd", "noisy", "bootstrap", "egreedy", "none"],
)
def test_every_explorer_trains_on_mountaincar_and_writes_its_run(tmp_path, exploration, compose_config, read_table):
    summary = train(compose_config(f"exploration={exploration}", "logger.log_every_updates=10"), tmp_path)
    assert summary["frames"] >= 300 and summary["q_updates"] >= 50  # 0.25 updates per frame after 100
    assert summary["method"] == f"dqn+{exploration}"
    assert (summary["dynamics_updates"] > 0) == (exploration not in ("rnd", "noisy", "bootstrap", "egreedy", "none"))
    episodes = read_table(tmp_path, "episodes")
    assert [int(row["episode"]) for row in episodes] == list(range(1, summary["episodes"] + 1))
    assert json.loads((tmp_path / "summary.json").read_text()) == summary
    assert (tmp_path / CHECKPOINT).exists()
    updates = read_table(tmp_path, "updates")
    assert updates and all(bool(row["loss_rnd"]) == (exploration == "rnd") for row in updates)
    assert all(float(row["loss_rnd"]) > 0 for row in updates if exploration == "rnd")  # the predictor's error, logged


@pytest.mark.parametrize("env", ["lunarlander", "acrobot", "cartpole"])
def test_other_supported_envs_train_with_gaussian_exploration(tmp_path, env, compose_config):
    summary = train(compose_config(f"env={env}"), tmp_path)
    assert summary["frames"] >= 300 and summary["dynamics_updates"] > 0
    assert summary["final_eval_return"] is not None


def test_deepsea_trains_at_the_configured_size_and_its_evaluations_play_the_same_grid(
    tmp_path, compose_config, read_table
):
    summary = train(compose_config("env=deepsea", "env.size=6", "eval.episodes=2", "eval.every_frames=96"), tmp_path)
    assert summary["env"] == "DeepSea-6" and summary["final_eval_return"] is not None  # the report keeps sizes apart
    assert {int(row["length"]) for row in read_table(tmp_path, "episodes")} == {6}  # one row down per step


def test_deepsea_runs_within_bsuites_budget_of_10000_episodes_and_stops_at_the_treasure(compose_default):
    cfg = compose_default("env=deepsea")
    assert (cfg.train.episodes, cfg.train.max_frames, cfg.train.stop_when_solved) == (10_000, None, True)
    assert (
        cfg.env.size == 10 and cfg.eval.episodes == cfg.eval.final_episodes == 1
    )  # deterministic: one episode says it


def test_a_deepsea_run_directory_names_its_size_and_its_summary_records_where_it_comes_from(tmp_path, run_app):
    result = run_app("env=deepsea", "env.size=6", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    summary_file = tmp_path / "runs" / "default" / "deepsea-6" / "dqn+diagonal" / "seed0" / "summary.json"
    record = json.loads(summary_file.read_text())["record"]  # the one-hot cells chose visit counts (the path)
    assert record["command"].startswith("python train.py env=deepsea env.size=6")
    assert len(record["commit"]) == 40 and record["cores"] >= 1 and record["device"] == "cpu"
    assert record["versions"]["torchrl"] == torchrl.__version__ and record["cpu"]


def test_n_step_windows_longer_than_a_batch_fill_across_batches(tmp_path, compose_config):
    summary = train(compose_config("env.num_envs=16", "collector.frames_per_batch=16", "algo.n_steps=3"), tmp_path)
    assert summary["frames"] >= 300 and summary["q_updates"] > 0


def test_batched_envs_and_prioritized_replay(tmp_path, compose_config):
    summary = train(compose_config("env.num_envs=4", "buffer=prioritized", "collector.frames_per_batch=32"), tmp_path)
    assert summary["frames"] >= 300 and summary["q_updates"] > 0


def test_paper_preset_decays_eps_by_0_9995_per_update(tmp_path, compose_config, read_table):
    cfg = compose_config(
        "experiment=paper_mountaincar",
        "algo.learning_starts=100",
        "train.max_frames=250",
        "collector.frames_per_batch=1",
    )
    assert cfg.algo.num_cells == [48] and cfg.algo.hard_update_interval == 8 and cfg.algo.lr == 0.05
    train(cfg, tmp_path)
    last = read_table(tmp_path, "episodes")[-1]
    decayed_steps = int(last["frames"]) - 1 - 100  # eps logged is the one that acted on the last frame
    assert float(last["eps"]) == pytest.approx(0.9995**decayed_steps, abs=2e-5)


def test_same_config_and_seed_give_the_same_returns(tmp_path, compose_config, read_table):
    cfg = compose_config("train.max_frames=600")
    first, second = train(cfg, tmp_path / "a"), train(cfg, tmp_path / "b")
    returns = [[row["return"] for row in read_table(tmp_path / run, "episodes")] for run in "ab"]
    assert returns[0] == returns[1] and len(returns[0]) >= 2
    assert first["final_eval_return"] == second["final_eval_return"]


def test_ctrl_c_saves_and_resume_continues_without_losing_or_repeating_frames(
    tmp_path, monkeypatch, compose_config, read_table
):
    cfg = compose_config("train.max_frames=480", "eval.final_episodes=0", "algo.n_steps=1")  # n-step holds frames back
    calls = {"n": 0}
    original = run_module._record_episodes

    def press_ctrl_c_at_the_tenth_batch(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 10:
            os.kill(os.getpid(), signal.SIGINT)
        return original(*args, **kwargs)

    monkeypatch.setattr(run_module, "_record_episodes", press_ctrl_c_at_the_tenth_batch)
    with pytest.raises(SystemExit, match="Interrupted at 160 frames"):
        train(cfg, tmp_path)
    monkeypatch.setattr(run_module, "_record_episodes", original)
    checkpoint = torch.load(tmp_path / CHECKPOINT, weights_only=True)
    assert checkpoint["frames"] == 160
    assert len(checkpoint["kept"]["replay_buffer"]["_storage"]["_storage"]["observation"]) >= 160

    cfg.resume = True
    summary = train(cfg, tmp_path)
    assert summary["frames"] == 480
    final = torch.load(tmp_path / CHECKPOINT, weights_only=True)
    assert int(final["kept"]["replay_buffer"]["_storage"]["_len"]) == 480  # every frame stored once
    episodes = [int(row["episode"]) for row in read_table(tmp_path, "episodes")]
    assert episodes == list(range(1, len(episodes) + 1))


@pytest.mark.parametrize(
    "overrides, message",
    [
        (["exploration.window=1"], "exploration.window=1: expected an integer >= 2"),
        (["exploration=diagonal", "exploration.window=1"], "exploration.window=1: expected an integer >= 2 .* or null"),
        (["buffer.size=-5"], "buffer.size=-5: expected a positive integer"),
        (["algo.batch_size=0"], "algo.batch_size=0: expected a positive integer"),
        (
            ["env.name=Pendulum-v1"],
            r"Pendulum-v1 has a Box\(-2.0, 2.0, \(1,\), float32\) action space; .* \(a Discrete action space\)",
        ),
        (["env.name=NoSuchEnv-v9"], "Unknown environment 'NoSuchEnv-v9'"),
        (
            ["env=lunarlander", "dynamics=oracle"],
            r"dynamics=oracle: lunarlander has no oracle dynamics \(those that have: mountaincar, deepsea\)",
        ),
        (["dynamics=table"], r"dynamics=table: mountaincar has no one-hot state \(a OneHot observation"),
        (
            ["env=deepsea", "dynamics=table", "exploration.horizon=2"],
            "dynamics=table: predicts from states, not from predictions; use exploration.horizon=1",
        ),
        (["env=deepsea", "dynamics=table", "population=2"], "dynamics=table: one table serves one run"),
        (["env.num_envs=3"], "collector.frames_per_batch=16: expected a multiple of env.num_envs=3"),
        (["algo.gamma=1.5"], r"algo.gamma=1.5: expected a discount in \[0, 1\]"),
        (["algo.gamma=-0.5"], r"algo.gamma=-0.5: expected a discount in \[0, 1\]"),
        (["train.max_frames=-5"], "train.max_frames=-5: expected a positive integer, or null"),
        (["exploration.model_error_threshold=-1"], "exploration.model_error_threshold=-1.0: expected a number >= 0"),
        (["algo.loss_function=foo"], "algo.loss_function='foo': expected one of l2, smooth_l1"),
        (["algo.soft_update_tau=5"], r"algo.soft_update_tau=5.0: expected a number in \(0, 1\]"),
        (
            ["algo.eps_end=0.5", "algo.eps_init=0.1"],
            r"algo \(eps_init, eps_end, eps_schedule\): Expected 0 <= eps_end <= eps_init <= 1, got eps_init=0.1, eps_end=0.5",
        ),
        (["algo.eps_end=0", "algo.eps_schedule=exponential"], "The exponential schedule needs eps_end > 0"),
        (["device=banana"], "device='banana': expected cpu, or cuda"),
        (["env.size=5"], r"env.size=5: mountaincar has no size \(those that have: deepsea\); leave it unset"),
        (
            ["env=deepsea", "+env.make_kwargs.depth=3"],
            r"env.make_kwargs: deepsea takes size, mapping_seed, .*, not depth",
        ),
        (["env=deepsea", "env.size=0"], r"env.size=0: expected a positive integer, or null"),
        (["dynamics.max_grad_norm=0"], "dynamics.max_grad_norm=0.0: expected a number > 0, or null"),
        (["exploration=diagonal", "exploration.min_variance=0"], "exploration.min_variance=0.0: expected a number > 0"),
        (
            ["exploration=diagonal", "exploration.added_variance=-1"],
            "exploration.added_variance=-1.0: expected a number >= 0",
        ),
        (
            ["dynamics.prior_num_cells=[0]"],
            r"dynamics.prior_num_cells=\[0\]: expected a non-empty list of positive layer sizes, or null",
        ),
        (["dynamics.output=softmax"], "dynamics.output='softmax': expected one of delta, categorical"),
        (
            ["dynamics.output=categorical"],
            r"dynamics \(output, normalize\): output='categorical' .* pass normalize=False",
        ),
    ],
)
def test_bad_config_values_get_one_clear_error(tmp_path, overrides, message, compose_config):
    with pytest.raises(ConfigError, match=message):
        train(compose_config(*overrides), tmp_path)
    assert not (tmp_path / CHECKPOINT).exists()


def test_a_finished_run_is_never_overwritten_and_foreign_checkpoints_are_refused(tmp_path, compose_config):
    train(compose_config("train.max_frames=120", "eval.final_episodes=0"), tmp_path)
    before = (tmp_path / "episodes.csv").read_text()
    with pytest.raises(ConfigError, match="already holds a run. Pass resume=true"):
        train(compose_config("train.max_frames=120"), tmp_path)
    with pytest.raises(ConfigError, match=r"another config; differing keys: algo.batch_size: 256 -> 32$"):
        train(compose_config("resume=true", "algo.batch_size=32"), tmp_path)
    assert (tmp_path / "episodes.csv").read_text() == before
    (tmp_path / CHECKPOINT).write_bytes(b"not a checkpoint")
    with pytest.raises(ConfigError, match="Cannot read .*checkpoint.pt"):
        train(compose_config("resume=true"), tmp_path)


def test_train_py_runs_and_prints_a_summary(tmp_path, run_app):
    result = run_app("env=mountaincar", "exploration=gaussian", f"hydra.run.dir={tmp_path}/run", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert '"method": "dqn+gaussian"' in result.stderr + result.stdout
    assert (tmp_path / "run" / "summary.json").exists()
    assert "Final greedy evaluation: 1 episodes side by side" in result.stdout + result.stderr
    last_line = (result.stdout + result.stderr).strip().splitlines()[-1]
    assert "SOLVED: final greedy return" in last_line and f"Run directory: {tmp_path}/run" in last_line
    assert "\x1b[" not in result.stdout + result.stderr  # no ANSI colour codes when piped
    bad = run_app("exploration.window=1", f"hydra.run.dir={tmp_path}/bad", cwd=tmp_path)
    assert bad.returncode == 1
    assert "Error: exploration.window=1" in bad.stderr and "Traceback" not in bad.stderr


def test_multirun_sweep_writes_one_run_per_job(tmp_path, run_app):
    result = run_app("-m", "exploration=gaussian,egreedy", f"hydra.sweep.dir={tmp_path}/sweep", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    methods = sorted(json.loads(p.read_text())["method"] for p in (tmp_path / "sweep").glob("*/summary.json"))
    assert methods == ["dqn+egreedy", "dqn+gaussian"]


def test_the_study_sweeps_through_submitit_local_and_the_report_compares_the_explorers(tmp_path, run_app):
    sweep = tmp_path / "sweep"
    overrides = (
        "experiment=study",
        "exploration=gaussian,egreedy",
        "seed=0",
        "population=2",
        "hydra/launcher=submitit_local",
        f"hydra.sweep.dir={sweep}",
    )
    result = run_app("-m", *overrides, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    summaries = [
        json.loads(p.read_text()) for p in sorted(sweep.glob("*/seed*/summary.json"))
    ]  # a population's members
    assert sorted((s["method"], s["seed"]) for s in summaries) == [
        ("dqn+egreedy", 0),
        ("dqn+egreedy", 1),
        ("dqn+gaussian", 0),
        ("dqn+gaussian", 1),
    ]
    assert {s["tag"] for s in summaries} == {"study"}
    assert list((sweep / ".submitit").iterdir())  # the jobs went through submitit
    report = subprocess.run(
        [sys.executable, "-m", "torchrl_mbe.report", str(sweep)], capture_output=True, text=True, timeout=300
    )
    assert report.returncode == 0, report.stderr
    results = (sweep / "report" / "results.md").read_text()
    exploration_rows = [line for line in results.split("### Exploration")[1].splitlines() if line.startswith("| dqn+")]
    assert [row.split(" | ")[0] for row in exploration_rows] == [
        "| dqn+egreedy",
        "| dqn+gaussian",
    ]  # coverage of both explorers' members


def test_the_slurm_launcher_config_selects_submitit_slurm(tmp_path, run_app):
    result = run_app("--cfg", "hydra", "experiment=study", "hydra/launcher=slurm", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert (
        "hydra_submitit_launcher.submitit_launcher.SlurmLauncher" in result.stdout
        and "cpus_per_task: 2" in result.stdout
    )


def test_wandb_logs_offline_into_the_run_dir(tmp_path, monkeypatch, compose_config):
    monkeypatch.setenv("WANDB_MODE", "offline")
    train(compose_config("logger=wandb", "train.max_frames=100", "eval.final_episodes=0"), tmp_path)
    assert list((tmp_path / "wandb").glob("offline-run-*"))


def test_mountaincar_defaults_to_3_step_returns_and_the_paper_to_1(compose_config):
    assert compose_config().algo.n_steps == 3 and compose_config("experiment=paper_mountaincar").algo.n_steps == 1


def test_the_gaussian_window_is_200_states_on_mountaincar_only_and_the_papers_50_in_its_presets(compose_config):
    window = lambda *overrides: compose_config(*overrides).exploration.window
    assert window() == window("exploration=gaussian") == 200
    assert window("exploration=kernel") == window("env=acrobot") == window("env=lunarlander") == 50
    assert window("experiment=paper_mountaincar") == window("experiment=coverage_mountaincar") == 50
    assert window("exploration.window=70") == 70
    assert "window" not in compose_config("experiment=paper_mountaincar", "exploration=egreedy").exploration


def test_resume_of_a_finished_run_changes_nothing_and_a_larger_budget_continues(tmp_path, compose_config, read_table):
    train(compose_config("train.max_frames=160", "eval.final_episodes=1"), tmp_path)
    before = {name: (tmp_path / name).read_bytes() for name in ("summary.json", "episodes.csv", "evaluations.csv")}
    again = train(compose_config("train.max_frames=160", "eval.final_episodes=1", "resume=true"), tmp_path)
    assert again == json.loads(before["summary.json"])
    assert {name: (tmp_path / name).read_bytes() for name in before} == before
    longer = train(compose_config("train.max_frames=320", "eval.final_episodes=1", "resume=true"), tmp_path)
    assert longer["frames"] == 320


def test_csv_headers_are_on_disk_before_the_first_row(tmp_path, compose_config, monkeypatch):
    seen = {}

    def look_at_the_files_at_the_first_batch(run, batch, **kwargs):
        seen.update({name: (tmp_path / f"{name}.csv").read_text() for name in ("episodes", "evaluations", "updates")})
        raise KeyboardInterrupt  # as a SIGKILL would, before anything else is written

    monkeypatch.setattr("torchrl_mbe.app.population.record_frames", look_at_the_files_at_the_first_batch)
    with pytest.raises(KeyboardInterrupt):
        train(compose_config(), tmp_path)
    assert seen["episodes"].startswith("episode,frames,return") and seen["evaluations"].startswith("frames,episode")


def test_episode_budget_is_exact_with_batched_envs(tmp_path, compose_config, read_table):
    summary = train(
        compose_config("env.num_envs=8", "collector.frames_per_batch=64", "train.episodes=3", "train.max_frames=null"),
        tmp_path,
    )
    assert summary["episodes"] == 3 and len(read_table(tmp_path, "episodes")) == 3


def test_best_policy_is_kept_and_the_summary_says_solved_or_not(tmp_path, compose_config, read_table):
    summary = train(compose_config("train.max_frames=400", "eval.episodes=1", "eval.every_frames=200"), tmp_path)
    evaluations = [float(row["eval_return_mean"]) for row in read_table(tmp_path, "evaluations")]
    assert summary["best_eval_return"] == max(evaluations[:-1])  # periodic ones; the last row is the final evaluation
    best = torch.load(tmp_path / BEST_POLICY, weights_only=True)
    assert best["eval_return_mean"] == summary["best_eval_return"] and best["frames"] == summary["best_eval_frames"]
    assert summary["solved"] is (summary["final_eval_return"] >= -110)


def test_evaluating_more_often_leaves_training_untouched(tmp_path, compose_config, read_table):
    """The stop's resolution (``eval.every_frames``) costs evaluation time only: the agent learns the same."""
    policies = {}
    for every_frames in (80, 10_000):
        run_dir = tmp_path / str(every_frames)
        train(compose_config("train.max_frames=400", "eval.episodes=2", f"eval.every_frames={every_frames}"), run_dir)
        policies[every_frames] = torch.load(run_dir / CHECKPOINT, weights_only=True)["agent"]["policy"]
    assert len(read_table(tmp_path / "80", "evaluations")) == 400 // 80 + 1  # the periodic ones and the final one
    torch.testing.assert_close(policies[80], policies[10_000], rtol=0, atol=0)


def test_stop_when_solved_ends_at_the_first_solved_evaluation(tmp_path, compose_config, monkeypatch):
    monkeypatch.setattr(
        population_module,
        "evaluate",
        lambda *args, **kwargs: {"eval_return_mean": -100.0, "eval_return_std": 0.0, "eval_success_rate": 1.0},
    )
    summary = train(
        compose_config(
            "train.stop_when_solved=true", "train.max_frames=2000", "eval.episodes=1", "eval.every_frames=160"
        ),
        tmp_path,
    )
    assert summary["frames"] == 160 and summary["solved_at_frames"] == 160 and summary["solved"] is True


def test_a_solved_evaluation_that_the_longer_one_does_not_confirm_lets_training_go_on(
    tmp_path, compose_config, monkeypatch
):
    confirmations = iter([-150.0, -105.0])  # the first confirmation fails, the second passes

    def fake_evaluate(actor, env, env_id):
        periodic = env.batch_size.numel() == 1
        return {
            "eval_return_mean": -100.0 if periodic else next(confirmations),
            "eval_return_std": 0.0,
            "eval_success_rate": 1.0,
        }

    monkeypatch.setattr(population_module, "evaluate", fake_evaluate)
    overrides = (
        "train.stop_when_solved=true",
        "train.max_frames=2000",
        "eval.episodes=1",
        "eval.every_frames=160",
        "eval.final_episodes=3",
    )
    summary = train(compose_config(*overrides), tmp_path)
    assert summary["frames"] == summary["solved_at_frames"] == 320
    assert (
        summary["final_eval_return"] == -105.0 and summary["solved"] is True
    )  # the confirming evaluation, not a third one


def test_checkpoints_of_version_0_1_are_refused_with_one_line(tmp_path, compose_config):
    train(compose_config("train.max_frames=120", "eval.final_episodes=0"), tmp_path)
    checkpoint = torch.load(tmp_path / CHECKPOINT, weights_only=True)
    del checkpoint["format"]
    torch.save(checkpoint, tmp_path / CHECKPOINT)
    with pytest.raises(
        ConfigError,
        match=r"checkpoint format 1 \(torchrl-mbe 0.1.0 wrote 1, 0.2.0 wrote 2, 0.3.0 wrote 3\); this version reads format 4 only",
    ):
        train(compose_config("train.max_frames=240", "resume=true"), tmp_path)


def test_resume_restores_the_target_network_and_its_update_counter(tmp_path, compose_config):
    summary = train(
        compose_config("train.max_frames=600", "eval.final_episodes=0", "algo.hard_update_interval=5"), tmp_path
    )
    saved = torch.load(tmp_path / CHECKPOINT, weights_only=True)["agent"]
    assert summary["q_updates"] % 6 != 0  # a counter mid-period, which a resume must not restart
    assert saved["target_updater_counter"] == summary["q_updates"] % 6  # HardUpdate counts 0..interval
    assert "q_loss" not in saved  # the Q weights are stored once, in the policy


@pytest.mark.parametrize("logger", ["csv", "wandb", "tensorboard"])
def test_a_default_run_makes_no_network_connection(tmp_path, run_app, logger):
    """The default run (and wandb offline) under an audit hook that records every non-loopback lookup or connect."""
    netlog = tmp_path / "network.log"
    site = Path(__file__).parent / "netguard_site"
    env = {"PYTHONPATH": str(site), "NETGUARD_LOG": str(netlog), "WANDB_MODE": None, "WANDB_ERROR_REPORTING": None}
    result = run_app(f"logger={logger}", f"hydra.run.dir={tmp_path}/run", "train.max_frames=200", cwd=tmp_path, env=env)
    assert result.returncode == 0, result.stderr
    assert not netlog.exists() or netlog.read_text() == ""
    assert "Run history" not in result.stdout + result.stderr  # wandb's summary block stays off


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the error on a machine without CUDA")
def test_device_cuda_without_a_gpu_is_refused_before_anything_runs(tmp_path, compose_config):
    with pytest.raises(ConfigError, match="device='cuda': CUDA is not available on this machine"):
        train(compose_config("device=cuda"), tmp_path)
    assert not any(tmp_path.iterdir())


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
@pytest.mark.parametrize("explorer", ["gaussian", "egreedy"])
def test_a_run_on_cuda_trains_end_to_end(tmp_path, compose_config, explorer):
    summary = train(
        compose_config("device=cuda", f"exploration={explorer}", "env.num_envs=4", "collector.frames_per_batch=32"),
        tmp_path,
    )
    assert summary["frames"] >= 300 and summary["q_updates"] > 0 and summary["final_eval_return"] is not None


@pytest.mark.parametrize("buffer", ["uniform", "prioritized"])
def test_a_run_creates_no_multiprocessing_semaphores_that_a_kill_would_leak(
    tmp_path, compose_config, monkeypatch, buffer
):
    import multiprocessing.synchronize

    created = []
    original = multiprocessing.synchronize.SemLock.__init__
    monkeypatch.setattr(
        multiprocessing.synchronize.SemLock,
        "__init__",
        lambda self, *a, **k: (created.append(type(self)), original(self, *a, **k))[1],
    )
    summary = train(compose_config(f"buffer={buffer}", "progress_bar=true"), tmp_path)
    assert summary["q_updates"] > 0 and created == []


def test_ctrl_c_during_the_final_evaluation_exits_with_the_checkpoint_and_the_resume_command(
    tmp_path, compose_config, monkeypatch
):
    def interrupted_evaluation(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(population_module, "evaluate", interrupted_evaluation)
    with pytest.raises(SystemExit, match=r"Interrupted at 304 frames; checkpoint saved in .*resume=true"):
        train(compose_config(), tmp_path)
    assert torch.load(tmp_path / CHECKPOINT, weights_only=True)["frames"] == 304
    assert not (tmp_path / "summary.json").exists()


def test_a_setting_added_since_0_2_leaves_the_config_id_of_runs_that_leave_it_at_its_old_behaviour(compose_config):
    from omegaconf import OmegaConf

    from torchrl_mbe.app.identity import config_id

    cfg = compose_config()
    as_0_2_wrote_it = OmegaConf.create(OmegaConf.to_container(cfg))
    del as_0_2_wrote_it.env["size"]  # 0.2.0 had no env.size
    del as_0_2_wrote_it.dynamics["output"]  # nor dynamics.output (its models predicted deltas)
    assert config_id(cfg) == config_id(as_0_2_wrote_it)  # the report groups old and new runs of one config together
    assert config_id(compose_config("env=deepsea", "env.size=10")) != config_id(
        compose_config("env=deepsea", "env.size=20")
    )
    categorical = compose_config("dynamics.output=categorical", "dynamics.normalize=false")
    assert config_id(categorical) != config_id(compose_config("dynamics.normalize=false"))
