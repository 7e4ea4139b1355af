"""DeepSea in the app: the planner's rule with the true dynamics (conf/experiment/deepsea_oracle.yaml) and with a learned model (deepsea_learned.yaml, deepsea_categorical.yaml)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from torchrl_mbe.app import train


def test_the_oracle_preset_solves_deepsea_10_where_dithering_needs_1000_episodes(compose_default, tmp_path):
    cfg = compose_default("experiment=deepsea_oracle", "env.size=10", "train.episodes=500")
    assert (
        cfg.exploration.window is None
        and cfg.env.num_envs == 1
        and cfg.algo.n_steps == 10
        and cfg.dynamics.name == "oracle"
    )
    summary = train(cfg, tmp_path)
    assert summary["solved"] and summary["episodes"] <= 300  # 2**10 = 1,024 episodes for dithering to find it once
    assert summary["first_success_episode"] <= 100


def test_a_population_plans_with_the_oracle_one_grid_per_member(compose_default, tmp_path, read_table):
    cfg = compose_default(
        "experiment=deepsea_oracle", "env.size=6", "population=2", "train.episodes=60", "eval.every_frames=120"
    )
    train(cfg, tmp_path)
    for seed in (0, 1):
        episodes = read_table(tmp_path / f"seed{seed}", "episodes")
        assert any(float(row["return"]) > 0.5 for row in episodes)  # both members found the treasure


@pytest.mark.slow  # a research preset (env=deepsea trains as the categorical one, tested below): the suite's longest run
def test_the_learned_preset_solves_deepsea_10_on_every_member_within_400_episodes(compose_default, tmp_path):
    # With the preset's earlier model (two standardized layers of 64, the default variance floor) seeds 0-4
    # solved 3 of 5 within 1,500 episodes (docs/results.md, section 6); dithering needs 1,024 to find it once.
    cfg = compose_default(
        "experiment=deepsea_learned", "env.size=10", "population=3", "train.episodes=400", "eval.every_frames=1000"
    )
    assert cfg.dynamics.name == "mlp" and cfg.dynamics.prior_scale > 0 and not cfg.dynamics.normalize
    for run_dir in train(cfg, tmp_path)["run_dirs"]:
        summary = json.loads((Path(run_dir) / "summary.json").read_text())
        assert summary["solved"], (
            f"member {summary['seed']} did not solve: {summary['episodes']} episodes, first treasure {summary['first_success_episode']}"
        )


def test_the_categorical_preset_solves_deepsea_10_on_every_member_within_400_episodes(compose_default, tmp_path):
    # A softmax model without the offset (the prior added to its logits) solved 0 of seeds 0-1 at N=10 (docs/results.md, section 6).
    cfg = compose_default(
        "experiment=deepsea_categorical", "env.size=10", "population=2", "train.episodes=400", "eval.every_frames=1000"
    )
    assert cfg.dynamics.output == "categorical" and cfg.dynamics.prior_scale > 0
    for run_dir in train(cfg, tmp_path)["run_dirs"]:
        summary = json.loads((Path(run_dir) / "summary.json").read_text())
        assert summary["solved"], (
            f"member {summary['seed']} did not solve: {summary['episodes']} episodes, first treasure {summary['first_success_episode']}"
        )


@pytest.mark.parametrize("population", [1, 2])
def test_the_count_bonus_is_learned_as_an_intrinsic_reward_that_falls_as_the_grid_is_visited(
    compose_default, tmp_path, read_table, population
):
    cfg = compose_default(
        "env=deepsea",
        "env.size=6",
        "exploration=counts",
        "exploration.intrinsic_coef=0.5",
        f"population={population}",
        "train.episodes=150",
        "train.stop_when_solved=false",
        "algo.learning_starts=60",
        "logger.log_every_updates=6",
    )
    train(cfg, tmp_path)
    for run_dir in [tmp_path] if population == 1 else [tmp_path / "seed0", tmp_path / "seed1"]:
        bonus = [float(row["intrinsic_reward"]) for row in read_table(run_dir, "updates")]
        assert all(0 < value <= 1 for value in bonus)  # 1 / sqrt(n + 1) of each visited cell's count
        assert bonus[-1] < bonus[0]  # the cells grow familiar


def test_a_replay_buffer_larger_than_the_memory_available_is_refused_in_one_line_before_training(
    compose_default, tmp_path, monkeypatch
):
    from torchrl_mbe.app import ConfigError, replay

    monkeypatch.setattr(replay, "_available_memory_bytes", lambda: 2**30)  # 1 GiB free
    cfg = compose_default("experiment=deepsea_oracle", "env.size=50", "population=5", "buffer.size=20000")
    with pytest.raises(
        ConfigError,
        match=r"buffer.size=20000: 5 x 20,000 transitions of 2,500-feature observations take about 2.8 GiB, more than the 1.0 GiB available",
    ):
        train(cfg, tmp_path)
    assert not (tmp_path / "seed0" / "episodes.csv").exists()


def test_a_replay_buffer_whose_checkpoints_do_not_fit_on_disk_is_refused_in_one_line_before_training(
    compose_default, tmp_path, monkeypatch
):
    # A checkpoint keeps the whole preallocated buffer: DeepSea-50's default run writes 3 GB at its first one.
    from torchrl_mbe.app import ConfigError, replay

    monkeypatch.setattr(replay, "_free_disk_bytes", lambda path: 2**30)  # 1 GiB free
    cfg = compose_default("experiment=deepsea_oracle", "env.size=50", "buffer.size=20000", "train.max_frames=100")
    run_dir = tmp_path / "run"
    with pytest.raises(
        ConfigError,
        match=rf"buffer.size=20000: 20,000 transitions .* take about 0.6 GiB, and every checkpoint keeps them: writing one needs 1.1 GiB, more than the 1.0 GiB free for {run_dir}",
    ):
        train(cfg, run_dir)
    assert not (run_dir / "episodes.csv").exists()


def test_deep_exploration_with_the_true_model_solves_deepsea_20_in_a_sixth_of_the_one_step_planners_episodes(
    compose_default, tmp_path, read_table
):
    # With the true dynamics the one-step planner (experiment=deepsea_oracle) needs hundreds of episodes at N = 20;
    # deep exploration solved seed 0 in 50 (docs/notes/deep-exploration.md).
    cfg = compose_default(
        "env=deepsea",
        "env.size=20",
        "exploration=deep",
        "dynamics=oracle",
        "exploration.value_weight=1.0",
        "train.episodes=100",
        "eval.every_frames=200",
    )
    summary = train(cfg, tmp_path)
    assert summary["solved"] and summary["episodes"] <= 80, summary["episodes"]
    losses = [float(row["loss_novelty_value"]) for row in read_table(tmp_path, "updates")]
    assert losses and all(loss >= 0 for loss in losses)  # the value of novelty trained beside the Q-network


def test_deep_exploration_on_cells_finds_deepsea_10_s_treasure_within_30_episodes_and_explores_back_to_it(
    compose_default, tmp_path, read_table
):
    # Value iteration on the transition table found the treasure at episodes 15, 19 and 21 on seeds 0-2, where the
    # categorical network with a learned U needed 110-170 episodes to solve (docs/notes/deep-exploration.md).
    cfg = compose_default("env=deepsea", "exploration=deep", "train.episodes=40", "train.stop_when_solved=false")
    summary = train(cfg, tmp_path)
    assert summary["method"] == "dqn+deep-table"  # the table, which one run on cells gets
    first = summary["first_success_episode"]
    assert first is not None and first <= 30, first
    after = [int(row["reached_goal"]) for row in read_table(tmp_path, "episodes")[first:]]
    assert sum(after) >= 0.8 * len(after), after  # the table's Q-values lead the exploring steps back to it
    assert summary["solved"]


def test_q_updates_wait_for_the_first_stored_transition_when_n_step_windows_hold_the_first_episode_back(
    compose_default, tmp_path
):
    # The preset's n-step windows span an episode, so the first episode is stored with the second: learning
    # from frame N on once sampled an empty buffer (DeepSea-100, where the preset starts at 100 frames).
    cfg = compose_default(
        "env=deepsea", "env.size=12", "exploration=deep", "algo.learning_starts=12", "train.episodes=4"
    )
    summary = train(cfg, tmp_path)
    assert summary["episodes"] == 4 and summary["q_updates"] > 0
