from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch
from tensordict import TensorDict
from torchrl.data import Categorical, Composite, OneHot
from torchrl.envs.utils import RandomPolicy

from torchrl_mbe import SUPPORTED_ENVS, make_env
from torchrl_mbe.envs import MountainCarDynamics, first_episodes, play_first_episodes


@pytest.mark.parametrize("name", list(SUPPORTED_ENVS))
def test_supported_envs_build_with_the_transforms_a_dqn_needs(name):
    env = make_env(name, seed=0)
    rollout = env.rollout(5)
    assert isinstance(env.action_spec, OneHot)
    assert rollout["observation"].dtype == torch.float32
    for key in ("step_count", "is_init", ("next", "episode_reward")):
        assert key in rollout.keys(True)
    assert make_env(SUPPORTED_ENVS[name]).action_spec.space.n == env.action_spec.space.n


def test_an_unknown_name_gets_one_clear_error_naming_what_is_supported():
    with pytest.raises(ValueError, match="Unknown environment 'mountain-car'") as error:
        make_env("mountain-car")
    assert "mountaincar (MountainCar-v0)" in str(error.value) and "module:EnvId" in str(error.value)


@pytest.mark.parametrize(
    "spec",
    [OneHot(3), Categorical(3), Composite(action=OneHot(3))],
    ids=["one-hot", "categorical", "a QValueActor's Composite"],
)
def test_oracle_dynamics_equals_gymnasium_mountaincar_step(spec):
    generator = torch.Generator().manual_seed(0)
    states = torch.stack(
        [torch.rand(200, generator=generator) * 1.8 - 1.2, torch.rand(200, generator=generator) * 0.14 - 0.07], -1
    )
    states[:10, 0] = -1.2  # at the left wall, moving left
    states[:10, 1] = -0.05
    actions = torch.randint(3, (200,), generator=generator)
    encoded = actions if isinstance(spec, Categorical) else torch.nn.functional.one_hot(actions, 3)
    td = TensorDict({"observation": states.double(), "action": encoded}, [200])
    predicted = MountainCarDynamics(spec)(td)["predicted_observation"]
    env = gym.make("MountainCar-v0").unwrapped
    env.reset(seed=0)
    expected = []
    for state, action in zip(states.double().numpy(), actions.tolist()):
        env.state = (float(state[0]), float(state[1]))
        expected.append(env.step(action)[0])
    torch.testing.assert_close(predicted.float(), torch.from_numpy(np.stack(expected)), atol=1e-6, rtol=0)


def test_a_gymnasium_batch_shape_is_a_grid_of_independent_copies_each_playing_its_own_first_episode():
    env = make_env("cartpole", num_envs=(2, 3), backend="gym", seed=0)  # a gymnasium-backed population's (num_envs, M)
    rollout = play_first_episodes(env, RandomPolicy(env.action_spec))
    assert env.batch_size == (2, 3) and rollout.shape[:2] == (2, 3)
    first_observations = rollout["observation"][..., 0, :].reshape(6, -1)
    assert len({tuple(row.tolist()) for row in first_observations}) == 6  # every copy seeded apart
    episodes = first_episodes(rollout.reshape(6, -1))
    ends = rollout["next", "done"].reshape(6, -1).int().argmax(-1)
    assert [episode.length for episode in episodes] == (
        ends + 1
    ).tolist()  # each copy's own first done, whatever the others do
    assert len(set(ends.tolist())) > 1  # so copies that finished first waited for the last
