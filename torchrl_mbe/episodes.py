"""Finished episodes in collected data, and what counts as reaching the goal."""
from __future__ import annotations

from dataclasses import dataclass

from tensordict import TensorDictBase

__all__ = ["Episode", "finished_episodes", "reached_goal"]

_GOAL_RULES = {
    "MountainCar-v0": "terminated",  # the car reached the flag
    "Acrobot-v1": "terminated",  # the tip swung above the line
    "LunarLander-v3": "landed",  # terminated at rest (+100), not crashed (-100)
    "CartPole-v1": "truncated",  # balanced until the time limit
}


@dataclass(frozen=True)
class Episode:
    """One finished episode: its return, length and how it ended."""

    episode_return: float
    length: int
    terminated: bool
    final_reward: float


def reached_goal(env_id: str, episode: Episode) -> bool:
    """Whether ``episode`` reached ``env_id``'s goal (an env's own termination by default).

    Examples:
        >>> from torchrl_mbe.episodes import Episode, reached_goal
        >>> reached_goal("MountainCar-v0", Episode(-120.0, 120, terminated=True, final_reward=-1.0))
        True
        >>> reached_goal("LunarLander-v3", Episode(-250.0, 80, terminated=True, final_reward=-100.0))
        False
    """
    rule = _GOAL_RULES.get(env_id, "terminated")
    if rule == "truncated":
        return not episode.terminated
    if rule == "landed":
        return episode.terminated and episode.final_reward > 0
    return episode.terminated


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
    ended = step[done]
    return [
        Episode(float(episode_return), int(length), bool(terminated), float(reward))
        for episode_return, length, terminated, reward in zip(
            ended["episode_reward"].reshape(-1).tolist(),
            ended["step_count"].reshape(-1).tolist(),
            ended["terminated"].reshape(-1).tolist(),
            ended["reward"].reshape(-1).tolist(),
        )
    ]
