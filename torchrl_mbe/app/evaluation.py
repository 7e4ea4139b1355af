"""Greedy evaluation: one episode in each copy of a batched env, under ``ExplorationType.DETERMINISTIC``, and what it says."""

from __future__ import annotations

import numpy as np
import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.envs import EnvBase, ExplorationType, set_exploration_type

from torchrl_mbe.envs import first_episodes, play_first_episodes, reached_goal

__all__ = ["evaluate", "evaluate_members", "play_episode"]


def evaluate(actor: TensorDictModuleBase, env: EnvBase, env_id: str) -> dict:
    """Greedy (``ExplorationType.DETERMINISTIC``) returns of one episode in each copy of a batched ``env``.

    All copies step together until each has finished one episode (one rollout,
    whatever the number of episodes).
    """
    return _episode_results(_greedy_rollout(actor, env), env_id)


def evaluate_members(actor: TensorDictModuleBase, env: EnvBase, env_id: str) -> list[dict]:
    """:func:`evaluate` of each member of a population ``actor`` in a ``(episodes, M)`` env, in one rollout."""
    rollout = _greedy_rollout(actor, env)
    return [_episode_results(rollout[:, member], env_id) for member in range(rollout.shape[1])]


def _greedy_rollout(actor: TensorDictModuleBase, env: EnvBase) -> TensorDictBase:
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        return play_first_episodes(env, actor)


def _episode_results(rollout: TensorDictBase, env_id: str) -> dict:
    """Mean and spread of the returns, and the success rate, of the first episode of each env of ``rollout`` (``(envs, time)``)."""
    episodes = first_episodes(rollout)
    returns = [episode.episode_return for episode in episodes]
    return {
        "eval_return_mean": float(np.mean(returns)),
        "eval_return_std": float(np.std(returns)),
        "eval_success_rate": float(np.mean([reached_goal(env_id, episode) for episode in episodes])),
    }


def play_episode(env: EnvBase, policy: TensorDictModuleBase) -> TensorDictBase:
    """One whole episode of ``policy`` in a single ``env``, shape ``(steps,)``, under the caller's exploration type."""
    return env.rollout(max_steps=100_000, policy=policy, break_when_any_done=True)
