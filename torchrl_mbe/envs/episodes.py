"""Finished episodes in collected data, and what counts as reaching the goal."""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym
import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.envs import EnvBase

from torchrl_mbe.envs.registry import GoalRule, task_of

__all__ = ["Episode", "finished_episodes", "first_episodes", "goal_rule", "play_first_episodes", "reached_goal"]


@dataclass(frozen=True)
class Episode:
    """One finished episode: its return, length and how it ended."""

    episode_return: float
    length: int
    terminated: bool
    final_reward: float


def reached_goal(env_id: str, episode: Episode) -> bool:
    """Whether ``episode`` reached ``env_id``'s goal: its registry ``Task.goal``, else :func:`goal_rule`'s.

    Examples:
        >>> from torchrl_mbe.envs.episodes import Episode, reached_goal
        >>> reached_goal("MountainCar-v0", Episode(-120.0, 120, terminated=True, final_reward=-1.0))
        True
        >>> reached_goal("LunarLander-v3", Episode(-250.0, 80, terminated=True, final_reward=-100.0))
        False
        >>> reached_goal("FrozenLake-v1", Episode(0.0, 6, terminated=True, final_reward=0.0))  # a hole
        False
    """
    task = task_of(env_id)
    rule = task.goal if task is not None else goal_rule(env_id)
    if rule == "truncated":
        return not episode.terminated
    if rule == "landed":
        return episode.terminated and episode.final_reward > 0
    return episode.terminated


def goal_rule(env_id: str) -> GoalRule:
    """The goal of a gymnasium task the registry does not know: ``"landed"`` (terminated with a positive last reward) when gymnasium's
    ``reward_threshold`` is positive (FrozenLake's goal, Taxi's drop-off; not a hole or a crash), else its own termination.

    Examples:
        >>> from torchrl_mbe.envs.episodes import goal_rule
        >>> goal_rule("FrozenLake-v1"), goal_rule("CliffWalking-v1")
        ('landed', 'terminated')
    """
    threshold = gym.spec(env_id).reward_threshold
    return "landed" if threshold is not None and threshold > 0 else "terminated"


def finished_episodes(batch: TensorDictBase) -> list[Episode]:
    """Episodes that end in a collected batch, in the order they ended.

    ``batch`` is a Collector batch of shape ``(time,)`` or ``(envs, time)`` from an
    env built by :func:`~torchrl_mbe.make_env` (``episode_reward`` and ``step_count``).
    """
    if batch.ndim == 2:
        batch = batch.transpose(0, 1)  # (time, envs): episodes in time order
    step = batch.reshape(-1)["next"]
    done = step["done"].reshape(-1)
    if not done.any():
        return []
    return _episodes_ending_at(step[done])


def first_episodes(rollout: TensorDictBase) -> list[Episode]:
    """The first episode of every env of a batched rollout of shape ``(envs, time)`` (or ``(time,)``).

    Meant for :func:`play_first_episodes` (or ``env.rollout(..., break_when_any_done=False,
    break_when_all_done=True)``): whatever follows an env's first episode (copies of its
    last step, or a new episode) is ignored.

    Examples:
        >>> import torch
        >>> from torchrl.envs import ExplorationType, set_exploration_type
        >>> from torchrl_mbe.envs import first_episodes, make_env
        >>> env = make_env("mountaincar", num_envs=3, seed=0)
        >>> rollout = env.rollout(1000, break_when_any_done=False, break_when_all_done=True)
        >>> [(episode.episode_return, episode.length) for episode in first_episodes(rollout)]
        [(-200.0, 200), (-200.0, 200), (-200.0, 200)]
    """
    if rollout.ndim == 1:  # a single env
        rollout = rollout.unsqueeze(0)
    done = rollout["next", "done"].reshape(*rollout.shape)
    if not done.any(-1).all():
        raise ValueError("every env of the rollout must finish an episode (use break_when_all_done=True).")
    end = done.int().argmax(-1)  # the first done step of each env
    return _episodes_ending_at(rollout["next"][torch.arange(rollout.shape[0]), end])


def play_first_episodes(env: EnvBase, policy: TensorDictModuleBase, max_steps: int = 100_000) -> TensorDictBase:
    """A rollout of ``policy`` in ``env``, shape ``(*env.batch_size, time)``, long enough for every copy to finish its first episode.

    Copies that have finished wait (``env.rollout(break_when_all_done=True)``'s
    partial steps, which every env of :func:`~torchrl_mbe.make_env` takes), so
    :func:`first_episodes` reads one episode per copy.

    Examples:
        >>> from torchrl.envs.utils import RandomPolicy
        >>> from torchrl_mbe.envs import first_episodes, make_env, play_first_episodes
        >>> env = make_env("cartpole", num_envs=(2, 3), backend="gym", seed=0)
        >>> rollout = play_first_episodes(env, RandomPolicy(env.action_spec))
        >>> rollout.shape[:2], len(first_episodes(rollout.reshape(6, -1)))
        (torch.Size([2, 3]), 6)
    """
    return env.rollout(max_steps=max_steps, policy=policy, break_when_any_done=False, break_when_all_done=True)


def _episodes_ending_at(last_steps: TensorDictBase) -> list[Episode]:
    """One :class:`Episode` per ``("next", ...)`` entry of an episode's last step (a flat batch)."""
    return [
        Episode(float(episode_return), int(length), bool(terminated), float(reward))
        for episode_return, length, terminated, reward in zip(
            last_steps["episode_reward"].reshape(-1).tolist(),
            last_steps["step_count"].reshape(-1).tolist(),
            last_steps["terminated"].reshape(-1).tolist(),
            last_steps["reward"].reshape(-1).tolist(),
        )
    ]
