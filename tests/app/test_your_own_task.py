"""The app on a task a user brings: any observation kind trains, the explorer follows the observation, bad input is one line."""

from __future__ import annotations

import json

import pytest
from omegaconf import OmegaConf

from torchrl_mbe.app import ConfigError, train
from torchrl_mbe.app.environments import config_observation_spec
from torchrl_mbe.app.explorers import EXPLORERS
from torchrl_mbe.app.observation import match_observation

pytest.importorskip("minigrid")


@pytest.mark.parametrize(
    "env_id, model",
    [
        ("FrozenLake-v1", "categorical"),  # Discrete: one-hot cells
        ("CliffWalking-v1", "categorical"),
        ("Blackjack-v1", "categorical"),  # Tuple of three Discrete
        ("MiniGrid-DoorKey-5x5-v0", "delta"),  # Dict: image codes (a Box), direction, mission text
        ("Acrobot-v1", "delta"),  # Box
    ],
)
def test_a_task_of_every_observation_kind_trains_with_the_model_its_observation_gets(
    tmp_path, compose_config, env_id, model
):
    summary = train(
        compose_config("env=gym", f"env.name={env_id}", "train.episodes=1000"), tmp_path
    )  # Blackjack's hands are short
    assert summary["frames"] >= 300 and summary["dynamics_updates"] > 0 and summary["final_eval_return"] is not None
    assert summary["method"] == ("dqn+diagonal" if model == "categorical" else "dqn+gaussian")


@pytest.mark.parametrize("exploration", list(EXPLORERS))
def test_every_explorer_trains_on_a_one_hot_task_with_what_it_names(tmp_path, compose_config, exploration):
    summary = train(compose_config("env=gym", "env.name=Taxi-v4", f"exploration={exploration}"), tmp_path)
    assert summary["frames"] >= 300 and summary["q_updates"] > 0
    matched = {"gaussian": "diagonal", "deep": "deep-table"}  # composed without a command line: what Taxi's cells get
    assert summary["method"] == f"dqn+{matched.get(exploration, exploration)}"


def test_env_deepsea_alone_trains_as_the_categorical_preset(compose_default):
    matched = compose_default("env=deepsea", "env.size=30")
    match_observation(matched, config_observation_spec(matched), named=set())
    preset = compose_default("experiment=deepsea_categorical", "env.size=30")
    settings = {
        key: OmegaConf.to_container(cfg, resolve=True) for key, cfg in (("matched", matched), ("preset", preset))
    }
    for differs in ("tag", "match_observation"):  # the preset's own run directories; it chooses its explorer itself
        for config in settings.values():
            config.pop(differs)
    assert settings["matched"] == settings["preset"]


@pytest.mark.parametrize("exploration", ["bootstrap", "egreedy", "rnd"])
def test_an_explorer_without_a_dynamics_model_gets_only_raw_inputs_on_a_one_hot_observation(
    compose_default, exploration
):
    cfg = compose_default("env=deepsea", f"exploration={exploration}")
    changes = match_observation(cfg, config_observation_spec(cfg), named={"exploration"})
    assert changes == ["algo.standardize_inputs=false"]


@pytest.mark.parametrize(
    "overrides, dynamics",
    [
        (["env=deepsea"], "table"),  # deep exploration of one run on cells
        (["env=gym", "env.name=FrozenLake-v1"], "table"),
        (["env=deepsea", "population=2"], "mlp"),  # one table serves one run: the categorical network
        (["env=deepsea", "exploration.horizon=2"], "mlp"),  # the table predicts from states only
        (["env=gym", "env.name=Blackjack-v1"], "mlp"),  # three categorical variables are not cells
    ],
)
def test_deep_exploration_on_cells_gets_the_transition_table(compose_default, overrides, dynamics):
    cfg = compose_default("exploration=deep", *overrides)
    match_observation(cfg, config_observation_spec(cfg), named={"exploration"})
    assert cfg.dynamics.name == dynamics
    assert cfg.dynamics.output == ("delta" if dynamics == "table" else "categorical")


def test_what_the_command_line_names_wins_over_the_observation(compose_default):
    cfg = compose_default("env=deepsea", "exploration=gaussian", "dynamics.num_cells=[32]")
    changes = match_observation(cfg, config_observation_spec(cfg), named={"exploration", "dynamics.num_cells"})
    assert changes == ["algo.standardize_inputs=false"]
    assert (
        cfg.exploration.name == "gaussian" and cfg.dynamics.output == "delta" and list(cfg.dynamics.num_cells) == [32]
    )


def test_a_vector_observation_keeps_the_configured_explorer(compose_default):
    cfg = compose_default("env=mountaincar")
    assert match_observation(cfg, config_observation_spec(cfg), named=set()) == []


def test_env_name_alone_uses_the_generic_settings_make_kwargs_reach_gymnasium_and_the_run_says_what_it_chose(
    tmp_path, run_app
):
    result = run_app(
        "env.name=FrozenLake8x8-v1", "+env.make_kwargs.is_slippery=false", "exploration.window=100", cwd=tmp_path
    )
    assert result.returncode == 0, result.stderr
    assert (
        "One-hot observation (64 entries, 1 categorical variable): dynamics.output=categorical"
        in result.stdout + result.stderr
    )  # the window named: exploration kept
    summary = json.loads(next((tmp_path / "runs").rglob("summary.json")).read_text())
    assert summary["env"] == "FrozenLake8x8-v1" and summary["method"] == "dqn+gaussian"
    assert summary["solved_threshold"] == 0.85  # gymnasium's reward_threshold
    config = OmegaConf.load(next((tmp_path / "runs").rglob(".hydra/config.yaml")))
    assert config.env.make_kwargs == {"is_slippery": False} and list(config.algo.num_cells) == [
        256,
        256,
    ]  # conf/tuned/gym_dqn.yaml


def test_a_minigrid_run_is_solved_by_its_success_rate(tmp_path, compose_config):
    summary = train(compose_config("env=minigrid", "env.name=MiniGrid-Empty-5x5-v0", "eval.final_episodes=2"), tmp_path)
    assert summary["solved_by"] == "success" and summary["solved_threshold"] == 0.9
    assert summary["solved"] == (summary["final_eval_success_rate"] >= 0.9)


@pytest.mark.parametrize(
    "overrides, message",
    [
        (
            ["env.name=FrozenLake-v1", "+env.make_kwargs.size=3"],
            r"FrozenLake-v1 does not take the keyword arguments \{'size': 3\}",
        ),
        (
            ["env.name=nosuchsuite:Thing-v0"],
            "nosuchsuite:Thing-v0 needs the package 'nosuchsuite', which is not installed",
        ),
        (
            ["env.name=MountainCarContinuous-v0"],
            r"MountainCarContinuous-v0 has a Box\(-1.0, 1.0, \(1,\), float32\) action space",
        ),
    ],
)
def test_a_task_the_app_cannot_train_is_one_line_before_any_work(tmp_path, compose_config, overrides, message):
    with pytest.raises(ConfigError, match=message):
        train(compose_config("env=gym", *overrides), tmp_path)
    assert not any(tmp_path.iterdir())
