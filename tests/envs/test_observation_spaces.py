"""Any discrete-action gymnasium task: every observation space read as one float vector, every unsupported one refused in one line."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium import spaces
from torchrl.data import MultiOneHot
from torchrl.envs import DoubleToFloat, GymEnv, TransformedEnv
from torchrl.envs.utils import RandomPolicy

from torchrl_mbe import make_env
from torchrl_mbe.envs import observations
from torchrl_mbe.envs.observations import MAX_EPISODE_STEPS, MAX_OBSERVATION_SIZE
from torchrl_mbe.modules.observations import categorical_groups

THREE_ACTIONS = spaces.Discrete(3)


class SpacesEnv(gym.Env):
    """A task of any observation and action space: random observations, an episode of 20 steps."""

    def __init__(self, observation_space: spaces.Space, action_space: spaces.Space = THREE_ACTIONS) -> None:
        self.observation_space, self.action_space = observation_space, action_space
        self.steps = 0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        if seed is not None:
            self.observation_space.seed(seed)
        self.steps = 0
        return self.observation_space.sample(), {}

    def step(self, action):
        self.steps += 1
        return self.observation_space.sample(), float(self.steps == 20), self.steps == 20, False, {}


SPACES = {
    "test/MultiDiscrete-v0": (spaces.MultiDiscrete([3, 4]), 7),
    "test/MultiBinary-v0": (spaces.MultiBinary(5), 10),  # five variables of two values
    "test/Image-v0": (spaces.Box(0, 255, (6, 6, 3), np.uint8), 108),
    "test/Dict-v0": (
        spaces.Dict(position=spaces.Box(-1.0, 1.0, (2,)), room=spaces.Discrete(4), note=spaces.Text(8)),
        6,
    ),
}
REFUSED = {
    "test/Text-v0": (spaces.Text(8), THREE_ACTIONS, "observation; accepted: Box, Discrete"),
    "test/Pixels-v0": (
        spaces.Box(0, 255, (64, 64, 3), np.uint8),
        THREE_ACTIONS,
        f"observation of 12288 numbers; at most {MAX_OBSERVATION_SIZE}",
    ),
    "test/MultiAction-v0": (spaces.Box(-1.0, 1.0, (2,)), spaces.MultiDiscrete([2, 2]), "MultiDiscrete"),
}
for env_id, (observation_space, *_) in SPACES.items():
    gym.register(env_id, entry_point=SpacesEnv, kwargs={"observation_space": observation_space})
for env_id, (observation_space, action_space, _) in REFUSED.items():
    gym.register(
        env_id, entry_point=SpacesEnv, kwargs={"observation_space": observation_space, "action_space": action_space}
    )


@pytest.mark.parametrize(
    "env_id, size",
    [
        ("FrozenLake-v1", 16),  # Discrete: one-hot
        ("Taxi-v4", 500),
        ("Blackjack-v1", 32 + 11 + 2),  # Tuple of three Discrete
        ("MiniGrid-DoorKey-5x5-v0", 7 * 7 * 3 + 4),  # Dict: the 7x7x3 codes and the direction; the mission text dropped
        *((env_id, size) for env_id, (_, size) in SPACES.items()),
    ],
)
def test_every_observation_space_is_one_float_vector_the_same_in_one_env_and_in_a_batch(env_id, size):
    single, batch = make_env(env_id, seed=3), make_env(env_id, num_envs=2, seed=3)
    assert single.observation_spec["observation"].shape == (size,) and batch.observation_spec["observation"].shape == (
        2,
        size,
    )
    assert torch.equal(
        batch.reset()["observation"][0], single.reset()["observation"]
    )  # the first copy is seeded as the single env
    rollout = single.rollout(30, RandomPolicy(single.action_spec))
    assert rollout["observation"].dtype == rollout["next", "observation"].dtype == torch.float32


@pytest.mark.parametrize(
    "env_id, groups",
    [
        ("Blackjack-v1", [32, 11, 2]),
        ("test/MultiDiscrete-v0", [3, 4]),
        ("test/MultiBinary-v0", [2] * 5),
    ],
)
def test_an_observation_of_categorical_variables_is_one_hot_per_variable_so_a_model_knows_which_entries_belong_together(
    env_id, groups
):
    env = make_env(env_id, seed=0)
    spec = env.observation_spec["observation"]
    assert isinstance(spec, MultiOneHot) and categorical_groups(spec) == tuple(groups)
    observations = env.rollout(30, RandomPolicy(env.action_spec))["observation"]
    assert all(  # exactly one entry of each variable is on, in every observation
        (part.sum(-1) == 1).all() for part in observations.split(groups, -1)
    )


@pytest.mark.parametrize("env_id", list(REFUSED))
def test_a_task_no_dqn_here_can_read_or_act_in_is_refused_in_one_line_naming_its_space(env_id):
    with pytest.raises(ValueError, match=REFUSED[env_id][2]) as error:
        make_env(env_id)
    assert "\n" not in str(error.value) and env_id in str(error.value)


def test_a_box_of_floats_is_read_as_torchrl_reads_it_so_mountaincar_steps_as_before():
    ours, torchrl = make_env("mountaincar", seed=5), TransformedEnv(GymEnv("MountainCar-v0"), DoubleToFloat())
    torchrl.set_seed(5)
    actions = torch.nn.functional.one_hot(torch.randint(3, (2000,), generator=torch.Generator().manual_seed(0)), 3)
    for env in (ours, torchrl):
        td = env.reset()
        observations = []
        for action in actions:
            td = env.step(td.set("action", action))
            observations.append(td["next", "observation"])
            td = env.step_mdp(td) if not td["next", "done"] else env.reset()
        env.observations = torch.stack(observations)
    assert torch.equal(ours.observations, torchrl.observations)


def test_a_task_without_a_time_limit_gets_one_and_the_callers_own_wins():
    def episode_length(env) -> int:  # always "up": CliffWalking's agent walks into the top wall and stays there
        up = env.action_spec.encode(torch.tensor(0))
        return env.rollout(5000, lambda td: td.set("action", up), break_when_any_done=True).shape[-1]

    assert episode_length(make_env("CliffWalking-v1")) == MAX_EPISODE_STEPS
    assert episode_length(make_env("CliffWalking-v1", max_episode_steps=50)) == 50


def _suite_ids(*entry_point_prefixes: str) -> list[str]:
    return sorted(
        env_id
        for env_id, spec in gym.registry.items()
        if isinstance(spec.entry_point, str) and spec.entry_point.startswith(entry_point_prefixes)
    )


@pytest.mark.parametrize("suite", ["gymnasium.envs.toy_text", "gymnasium.envs.classic_control", "minigrid"])
def test_every_id_of_gymnasiums_toy_text_and_classic_control_and_of_minigrid_steps_or_is_refused_in_one_line(suite):
    pytest.importorskip("minigrid")
    refused = {}
    for env_id in _suite_ids(suite):
        try:
            env = make_env(env_id, seed=0)
        except ValueError as error:
            refused[env_id] = str(error)
            continue
        rollout = env.rollout(20, RandomPolicy(env.action_spec))
        assert rollout["next", "observation"].dtype == torch.float32 and rollout["next", "observation"].ndim == 2, (
            env_id
        )
    assert all("\n" not in message and env_id in message for env_id, message in refused.items())
    continuous = {"MountainCarContinuous-v0", "Pendulum-v1"}
    assert set(refused) == (continuous if suite.endswith("classic_control") else {i for i in refused if "WFC" in i}), (
        refused
    )


def test_a_dropped_text_entry_is_said_once_however_many_env_copies_drop_it(monkeypatch):
    said = []
    monkeypatch.setattr(observations.log, "info", lambda message, *args: said.append(message % args))
    observations._log_dropped.cache_clear()  # what earlier tests of this process said
    make_env("MiniGrid-Empty-6x6-v0", num_envs=3, seed=0)
    make_env("MiniGrid-Empty-6x6-v0", seed=1)
    assert said == [
        "MiniGrid-Empty-6x6-v0: the observation entries ['mission'] are dropped (not a fixed number of numbers)"
    ]
