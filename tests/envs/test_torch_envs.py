"""What every torch-batched classic-control env shares with its gymnasium original: specs, time limit, seeding."""

from __future__ import annotations

import gymnasium as gym
import pytest
import torch
from torchrl.envs import GymEnv
from torchrl.envs.utils import check_env_specs

from torchrl_mbe import make_env
from torchrl_mbe.envs import BatchedAcrobotEnv, BatchedCartPoleEnv, BatchedMountainCarEnv

TORCH_ENVS = {"mountaincar": BatchedMountainCarEnv, "cartpole": BatchedCartPoleEnv, "acrobot": BatchedAcrobotEnv}
GYM_IDS = {"mountaincar": "MountainCar-v0", "cartpole": "CartPole-v1", "acrobot": "Acrobot-v1"}


@pytest.mark.parametrize("name", sorted(TORCH_ENVS))
@pytest.mark.parametrize("batch_shape", [(1,), (5,), (2, 3)], ids=str)
def test_specs_and_time_limit_match_gymenv_and_pass_torchrl_checks(name, batch_shape):
    env = TORCH_ENVS[name](batch_shape, seed=0)
    check_env_specs(env)
    reference = GymEnv(GYM_IDS[name])
    assert env.batch_size == batch_shape
    assert env.max_episode_steps == gym.spec(GYM_IDS[name]).max_episode_steps
    for spec in ("full_observation_spec", "full_action_spec", "full_reward_spec", "full_done_spec"):
        assert getattr(env, spec) == getattr(reference, spec).expand(*batch_shape).to("cpu"), spec
    check_env_specs(make_env(name, num_envs=5, backend="torch", seed=0))  # as the app wraps it


@pytest.mark.parametrize("name", sorted(TORCH_ENVS))
def test_same_seed_same_episodes_other_seed_other_episodes(name):
    def rollout(seed: int):
        torch.manual_seed(0)  # the random actions
        return TORCH_ENVS[name](3, seed=seed).rollout(250, break_when_any_done=False)

    first, again, other = rollout(7), rollout(7), rollout(8)
    assert torch.equal(first["observation"], again["observation"])
    assert torch.equal(first["next", "done"], again["next", "done"])
    assert not torch.equal(first["observation"][:, 0], other["observation"][:, 0])
