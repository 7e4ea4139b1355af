"""The env tests' shared helper: an episode of gymnasium's own env, replayed from a given state."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch


def play_gymnasium_episode(
    env_id: str, state: torch.Tensor, actions: torch.Tensor, **make_kwargs
) -> tuple[torch.Tensor, list[tuple[float, bool, bool]], torch.Tensor]:
    """``gym.make(env_id)`` (its TimeLimit included) from ``state`` under ``actions`` until done:
    the observations, ``(reward, terminated, truncated)`` per step and the last state."""
    env = gym.make(env_id, **make_kwargs)
    env.reset(seed=0)
    env.unwrapped.state = state.numpy().copy()
    observations, outcomes = [], []
    for action in actions.tolist():
        observation, reward, terminated, truncated, _ = env.step(action)
        observations.append(observation)
        outcomes.append((reward, terminated, truncated))
        if terminated or truncated:
            break
    return torch.from_numpy(np.stack(observations)), outcomes, torch.from_numpy(np.asarray(env.unwrapped.state))


@pytest.fixture
def gymnasium_episode():
    """``gymnasium_episode(env_id, state, actions, **make_kwargs)``: see :func:`play_gymnasium_episode`."""
    return play_gymnasium_episode
