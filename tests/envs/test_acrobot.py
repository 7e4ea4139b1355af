from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import torch
from gymnasium.envs.classic_control import acrobot as gym_acrobot
from torchrl.envs import GymWrapper
from torchrl.envs.utils import check_env_specs

from torchrl_mbe import make_env
from torchrl_mbe.envs import BatchedAcrobotEnv
from torchrl_mbe.envs.acrobot import ACROBOT, _wrap

VELOCITY_BOUNDS = (ACROBOT["max_vel_1"], ACROBOT["max_vel_2"])


def one_hot(actions: torch.Tensor) -> torch.Tensor:
    return torch.nn.functional.one_hot(actions, 3)


def test_start_states_are_float32_draws_uniform_in_gymnasiums_range():
    env = BatchedAcrobotEnv(4096, seed=0)
    observation = env.reset()["observation"]
    state = env.physical_state
    assert state.abs().max() <= 0.1 + 1e-8  # float32(0.1) is a hair above 0.1
    assert (state.amin(0) < -0.0995).all() and (state.amax(0) > 0.0995).all()
    assert torch.equal(state, state.float().double())  # gymnasium rounds its draw to float32
    torch.testing.assert_close(state.mean(0), torch.zeros(4, dtype=torch.float64), atol=0.006, rtol=0)
    angles, velocities = state[:, :2], state[:, 2:]
    expected = torch.stack([angles[:, 0].cos(), angles[:, 0].sin(), angles[:, 1].cos(), angles[:, 1].sin()], -1)
    torch.testing.assert_close(observation, torch.cat([expected, velocities], -1).float())


def test_angle_wrapping_equals_gymnasiums_wrap():
    x = torch.tensor([0.0, math.pi, -math.pi, 3.5, -3.5, 7.0, -7.0, 10.0, -13.0, 3 * math.pi], dtype=torch.float64)
    expected = torch.tensor([gym_acrobot.wrap(value, -math.pi, math.pi) for value in x.tolist()], dtype=torch.float64)
    torch.testing.assert_close(_wrap(x, -math.pi, math.pi), expected, rtol=0, atol=1e-15)


def test_one_step_equals_gymnasiums_from_states_all_over_the_state_space():
    """Any angles, velocities up to and at the bounds, every action: the same next state, observation, reward, end."""
    num_states = 400
    generator = torch.Generator().manual_seed(0)
    high = torch.tensor([math.pi, math.pi, *VELOCITY_BOUNDS], dtype=torch.float64)
    states = (2 * torch.rand(num_states, 4, generator=generator, dtype=torch.float64) - 1) * high
    states[:40, 2:] = high[2:] * torch.randint(2, (40, 2), generator=generator).mul(2).sub(1)  # at the bounds
    actions = torch.randint(3, (num_states,), generator=generator)
    env = BatchedAcrobotEnv(num_states, seed=0)
    td = env.reset()
    env.physical_state.copy_(states)
    ours = env.step(td.set("action", one_hot(actions)))["next"]
    reference = gym.make("Acrobot-v1").unwrapped
    reference.reset(seed=0)
    next_states, observations, outcomes = [], [], []
    for state, action in zip(states.numpy(), actions.tolist()):
        reference.state = state.copy()
        observation, reward, terminated, _, _ = reference.step(action)
        next_states.append(reference.state)
        observations.append(observation)
        outcomes.append((reward, terminated))
    torch.testing.assert_close(env.physical_state, torch.from_numpy(np.stack(next_states)), rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(ours["observation"], torch.from_numpy(np.stack(observations)), rtol=0, atol=1e-6)
    assert list(zip(ours["reward"].squeeze(-1).tolist(), ours["terminated"].squeeze(-1).tolist())) == outcomes
    next_state = env.physical_state
    for dim, bound in zip((2, 3), VELOCITY_BOUNDS):
        assert (next_state[:, dim] == bound).any() and (next_state[:, dim] == -bound).any(), "velocities clipped"
    assert ((next_state[:, :2] - states[:, :2]).abs() > math.pi).any(), "angles wrapped"
    assert 0 < sum(terminated for _, terminated in outcomes) < num_states


def test_trajectories_equal_gymnasiums_over_200_steps_including_termination_and_truncation(gymnasium_episode):
    """From starts, near the bar and at top speed, under random torques: the same steps; truncation at the limit."""
    num_envs, horizon = 16, 200
    env = BatchedAcrobotEnv(num_envs, max_episode_steps=horizon, seed=0)
    td = env.reset()
    special = torch.tensor(
        [
            [2.05, 0.0, 1.0, 0.0],  # rising to the bar: over it after one step
            [-2.05, 0.0, -1.0, 0.0],
            [2.05, 0.0, -1.0, 0.0],  # just under the bar, falling away
            [0.0, 0.0, 4 * math.pi, -9 * math.pi],  # at both velocity bounds
            [1.0, -2.0, -4 * math.pi, 9 * math.pi],
        ],
        dtype=torch.float64,
    )
    env.physical_state[: len(special)] = special
    starts = env.physical_state.clone()
    actions = torch.randint(3, (horizon, num_envs), generator=torch.Generator().manual_seed(0))
    ours, states = [], []
    for t in range(horizon):
        td = env.step(td.set("action", one_hot(actions[t])))["next"]
        ours.append(td.clone())
        states.append(env.physical_state.clone())
    ours, states = torch.stack(ours, 1), torch.stack(states, 1)
    lengths = []
    for i in range(num_envs):
        observations, outcomes, final_state = gymnasium_episode(
            "Acrobot-v1", starts[i], actions[:, i], max_episode_steps=horizon
        )
        length = len(outcomes)
        torch.testing.assert_close(ours[i, :length]["observation"], observations, atol=1e-5, rtol=0)
        assert outcomes == list(
            zip(*(ours[i, :length][key].squeeze(-1).tolist() for key in ("reward", "terminated", "truncated")))
        ), i
        torch.testing.assert_close(states[i, length - 1], final_state, atol=1e-9, rtol=0)  # no drift
        lengths.append(length)
    assert lengths[:2] == [1, 1] and lengths[2] > 1 and min(lengths[5:]) > 50
    assert lengths.count(horizon) >= 8 and ours[:, -1]["truncated"].all()


def test_partial_reset_of_a_two_dimensional_batch_restarts_only_the_masked_envs():
    env = BatchedAcrobotEnv((2, 2), seed=0)
    td = env.reset()
    for _ in range(5):
        td = env.step(td.set("action", one_hot(torch.full((2, 2), 2))))["next"]
    before = env.physical_state.clone()
    reset = torch.tensor([[True, False], [False, True]])
    env.reset(td.set("_reset", reset.unsqueeze(-1)))
    after = env.physical_state
    assert torch.equal(after[~reset], before[~reset])
    assert after[reset].abs().max() <= 0.1 and (after[reset] != before[reset]).all()
    assert env.elapsed_steps.tolist() == [[0, 5], [5, 0]]


def test_make_env_steps_several_acrobots_in_torch_and_its_seed_reproduces_them():
    def rollout(seed: int):
        torch.manual_seed(0)  # the random actions
        env = make_env("acrobot", num_envs=4, seed=seed)
        assert isinstance(env.base_env, BatchedAcrobotEnv) and env.batch_size == (4,)
        return env.rollout(50)

    first, again, other = rollout(3), rollout(3), rollout(4)
    assert torch.equal(first["observation"], again["observation"])
    assert not torch.equal(first["observation"][:, 0], other["observation"][:, 0])
    check_env_specs(make_env("acrobot", num_envs=4, seed=0))
    assert isinstance(make_env("acrobot").base_env, GymWrapper)
