"""DeepSea in the app: the planner's rule alone, with the true dynamics (conf/experiment/deepsea_oracle.yaml)."""
from __future__ import annotations

from torchrl_mbe.app import train


def test_the_oracle_preset_solves_deepsea_10_where_dithering_needs_1000_episodes(compose_default, tmp_path):
    cfg = compose_default("experiment=deepsea_oracle", "env.size=10", "train.episodes=500")
    assert cfg.exploration.window is None and cfg.env.num_envs == 1 and cfg.algo.n_steps == 10 and cfg.dynamics.name == "oracle"
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
