"""Exploration and learning metrics computed from what a run wrote to disk.

Everything here is a pure NumPy function of arrays: visited states
``(num_steps, obs_dim)`` for coverage, per-episode returns and goal flags for
learning statistics. Coverage grids are laid over each environment's fixed box
(the registry's ``Task.bounds``), so that coverage figures of different runs
and methods are comparable.

Coverage, two measures:

- :func:`grid_coverage`: the fraction of cells of a ``bins x bins`` grid over
  two chosen dimensions that at least one visited state falls in. States outside
  the box count in the nearest edge cell. Over MountainCar's (position,
  velocity) this is the quantity the paper's Figure 1 shows by eye.
- :func:`pairwise_coverage`: for higher-dimensional states (LunarLander, 8 dims)
  a grid over all dimensions at once has ``bins ** 8`` cells, almost all
  unreachable, so its occupied fraction says nothing. Instead we average
  :func:`grid_coverage` over every pair of the environment's continuous
  dimensions: each 2-D grid is small enough to fill, and pairs (unlike 1-D
  histograms) still see correlated spreading such as "fast while high up".
  Boolean dimensions (LunarLander's leg contacts) are left out: they can fill at
  most 2 of ``bins`` rows and would only drag every pair down.
"""

from __future__ import annotations

import itertools
import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from torchrl_mbe.envs.registry import EnvBounds

__all__ = [
    "EpisodeStats",
    "episode_stats",
    "grid_coverage",
    "loglog_slope",
    "max_position",
    "pairwise_coverage",
    "running_average",
]


def _as_states(states: np.ndarray) -> np.ndarray:
    states = np.asarray(states, dtype=np.float64)
    if states.ndim != 2:
        raise ValueError(f"states must have shape (num_steps, obs_dim), got shape {states.shape}.")
    if not np.isfinite(states).all():
        raise ValueError("states contain NaN or infinite values.")
    return states


def grid_coverage(
    states: np.ndarray,
    low: Sequence[float],
    high: Sequence[float],
    bins: int = 20,
    *,
    dims: Sequence[int] = (0, 1),
) -> float:
    """Fraction of the cells of a regular grid over ``dims`` holding at least one state.

    The box ``[low, high]`` over the chosen dimensions is cut into ``bins`` equal
    intervals per dimension (``bins ** len(dims)`` cells); a state outside the box
    counts in the nearest edge cell.

    Args:
        states (np.ndarray): visited states, shape ``(num_steps, obs_dim)``.
        low (sequence of float): lower bound of each of ``dims``.
        high (sequence of float): upper bound of each of ``dims``.
        bins (int): cells per dimension. Defaults to 20.

    Keyword Args:
        dims (sequence of int): which state dimensions span the grid. Defaults to ``(0, 1)``.

    Returns:
        float: the covered fraction in ``[0, 1]``; 0 for no states.

    Examples:
        >>> import numpy as np
        >>> low, high = (-1.2, -0.07), (0.6, 0.07)  # MountainCar (position, velocity)
        >>> grid_coverage(np.array([[-0.5, 0.0]]), low, high)
        0.0025
        >>> grid_coverage(np.array([[-9.0, 0.0], [-1.2, 0.0]]), low, high)  # clipped into the same cell
        0.0025
    """
    states = _as_states(states)
    dims = list(dims)
    low, high = np.asarray(low, dtype=np.float64), np.asarray(high, dtype=np.float64)
    if low.shape != (len(dims),) or high.shape != (len(dims),) or not (high > low).all():
        raise ValueError(f"low and high must give one bound per dim of {dims} with high > low; got {low}, {high}.")
    if len(states) == 0:
        return 0.0
    cells = np.floor((states[:, dims] - low) / (high - low) * bins).astype(np.int64).clip(0, bins - 1)
    occupied = np.unique(np.ravel_multi_index(tuple(cells.T), (bins,) * len(dims)))
    return occupied.size / bins ** len(dims)


def pairwise_coverage(states: np.ndarray, bounds: EnvBounds, bins: int = 20) -> float:
    """Mean :func:`grid_coverage` over every pair of ``bounds.coverage_dims``.

    Args:
        states (np.ndarray): visited states, shape ``(num_steps, obs_dim)``.
        bounds (EnvBounds): the environment's box, e.g. ``TASKS["lunarlander"].bounds``.
        bins (int): cells per dimension of every pair grid. Defaults to 20.

    Examples:
        >>> import numpy as np
        >>> bounds = EnvBounds(low=(0.0, 0.0, 0.0), high=(1.0, 1.0, 1.0), labels=("a", "b", "c"))
        >>> pairwise_coverage(np.array([[0.1, 0.1, 0.1], [0.9, 0.9, 0.1]]), bounds, bins=2)
        0.5
    """
    pairs = list(itertools.combinations(bounds.coverage_dims, 2))
    if not pairs:
        raise ValueError(f"pairwise coverage needs at least two dims, got {bounds.coverage_dims}.")
    coverages = [
        grid_coverage(states, (bounds.low[i], bounds.low[j]), (bounds.high[i], bounds.high[j]), bins, dims=(i, j))
        for i, j in pairs
    ]
    return float(np.mean(coverages))


def running_average(returns: np.ndarray, window: int = 100) -> np.ndarray:
    """Trailing mean of the last ``window`` returns at every episode.

    Entry ``i`` (0-based) is the mean of episodes ``max(0, i - window + 1) .. i``:
    before ``window`` episodes exist it averages all of them so far, so the curve
    starts at the first episode instead of at episode ``window``.

    Examples:
        >>> running_average(np.array([0.0, 2.0, 4.0, 6.0]), window=2)
        array([0., 1., 3., 5.])
    """
    returns = np.asarray(returns, dtype=np.float64)
    cumsum = np.concatenate([[0.0], np.cumsum(returns)])
    ends = np.arange(1, len(returns) + 1)
    starts = np.maximum(ends - window, 0)
    return (cumsum[ends] - cumsum[starts]) / (ends - starts)


@dataclass(frozen=True)
class EpisodeStats:
    """Learning statistics of one run; episodes are numbered from 1.

    Attributes:
        num_episodes (int): finished training episodes.
        first_success_episode (int or None): first episode that reached the goal.
        num_successes (int): episodes that reached the goal.
        best_running_average (float or None): best mean return over ``window``
            consecutive episodes (over all of them if the run is shorter).
        final_running_average (float or None): mean return of the last ``window`` episodes.
        solved_episode (int or None): first episode at which the mean over the last
            full ``window`` episodes reached the solved threshold (gymnasium's
            definition: a shorter run is never solved).
    """

    num_episodes: int
    first_success_episode: int | None
    num_successes: int
    best_running_average: float | None
    final_running_average: float | None
    solved_episode: int | None


def _first_episode(mask: np.ndarray) -> int | None:
    hits = np.flatnonzero(mask)
    return int(hits[0]) + 1 if hits.size else None


def episode_stats(
    returns: np.ndarray, reached_goal: np.ndarray, solved_threshold: float | None, *, window: int = 100
) -> EpisodeStats:
    """Statistics of a run's episode table (one row per episode, in order, from episode 1).

    Args:
        returns (np.ndarray): return of every episode.
        reached_goal (np.ndarray): 0/1 (or bool) per episode, 1 if it terminated at the goal.
        solved_threshold (float or None): mean return over ``window`` episodes that
            counts as solved; ``None`` for a task without one (never solved).

    Keyword Args:
        window (int): running-average window. Defaults to 100.

    Examples:
        >>> import numpy as np
        >>> stats = episode_stats(np.array([-200.0, -150.0, -100.0, -90.0]), np.array([0, 1, 1, 1]), -110.0, window=2)
        >>> stats.first_success_episode, stats.num_successes, stats.solved_episode
        (2, 3, 4)
        >>> stats.best_running_average, stats.final_running_average
        (-95.0, -95.0)
    """
    returns = np.asarray(returns, dtype=np.float64)
    reached_goal = np.asarray(reached_goal).astype(bool)
    if returns.shape != reached_goal.shape or returns.ndim != 1:
        raise ValueError(
            f"returns and reached_goal must be 1-D of equal length, got {returns.shape} and {reached_goal.shape}."
        )
    num_episodes = len(returns)
    if num_episodes == 0:
        return EpisodeStats(0, None, 0, None, None, None)
    averages = running_average(returns, window)
    full = min(window, num_episodes)
    solved = np.zeros(num_episodes, dtype=bool)
    if solved_threshold is not None:
        solved[window - 1 :] = averages[window - 1 :] >= solved_threshold
    return EpisodeStats(
        num_episodes=num_episodes,
        first_success_episode=_first_episode(reached_goal),
        num_successes=int(reached_goal.sum()),
        best_running_average=float(averages[full - 1 :].max()),
        final_running_average=float(averages[-1]),
        solved_episode=_first_episode(solved),
    )


def max_position(states: np.ndarray, dim: int = 0) -> float:
    """Largest value of one state dimension over the visited states (MountainCar: position).

    Examples:
        >>> import numpy as np
        >>> max_position(np.array([[-0.5, 0.0], [0.3, 0.01], [0.1, -0.02]]))
        0.3
    """
    states = _as_states(states)
    if len(states) == 0:
        raise ValueError("max_position needs at least one state.")
    return float(states[:, dim].max())


def loglog_slope(sizes: Sequence[float], values: Sequence[float]) -> float | None:
    """The least-squares slope ``k`` of ``log(value)`` on ``log(size)``: values grow like ``size ** k``.

    ``None`` for fewer than two distinct sizes (no line to fit).

    Examples:
        >>> round(loglog_slope([10, 20, 40], [100, 400, 1600]), 6)
        2.0
        >>> loglog_slope([10, 20], [400, 400])
        0.0
        >>> loglog_slope([10], [100]) is None
        True
    """
    if len(set(sizes)) < 2:
        return None
    return statistics.linear_regression([math.log(size) for size in sizes], [math.log(value) for value in values]).slope
