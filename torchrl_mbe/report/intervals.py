"""Comparisons across tasks with confidence intervals (Agarwal et al. 2021, "Deep RL at the edge of the statistical precipice").

The interquartile mean (IQM) of scores pooled over tasks and seeds, its stratified
bootstrap 95% confidence interval (seeds resampled with replacement within each
task), and performance profiles (the fraction of runs scoring above each threshold),
computed as the ``rliable`` package computes them (``aggregate_iqm`` is SciPy's
``trim_mean(..., 0.25)``; intervals by the percentile method), in NumPy.

Scores are per task: ``{task: array of one score per seed}``; tasks may have different
numbers of seeds.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

__all__ = ["iqm", "performance_profile", "stratified_bootstrap_ci"]


def iqm(scores: np.ndarray | Sequence[float]) -> float:
    """The interquartile mean: the mean of the scores left after cutting ``floor(n / 4)`` from each end.

    Examples:
        >>> from torchrl_mbe.report.intervals import iqm
        >>> iqm([0.0, 1.0, 2.0, 3.0, 100.0, 4.0, 5.0, 6.0])  # 0, 1 and 6, 100 cut
        3.5
    """
    values = np.sort(np.asarray(scores, dtype=float).ravel())
    cut = len(values) // 4
    return float(values[cut : len(values) - cut].mean())


def stratified_bootstrap_ci(
    scores: dict[str, np.ndarray],
    statistic: Callable[[np.ndarray], float] = iqm,
    *,
    reps: int = 2000,
    confidence: float = 0.95,
    seed: int = 0,
) -> tuple[float, float, float]:
    """``statistic`` of the pooled scores and its stratified bootstrap confidence interval.

    Each of ``reps`` resamples draws, for every task, as many seeds as it has, with
    replacement, from that task's seeds (so every task keeps its weight); the interval
    is the ``(1 - confidence) / 2`` and ``(1 + confidence) / 2`` percentiles of the
    resampled statistic.

    Returns:
        ``(point estimate, lower, upper)``.

    Examples:
        >>> import numpy as np
        >>> from torchrl_mbe.report.intervals import stratified_bootstrap_ci
        >>> point, low, high = stratified_bootstrap_ci({"a": np.array([0.2, 0.4, 0.6]), "b": np.array([1.0, 1.0])})
        >>> round(point, 3), low <= point <= high
        (0.667, True)
    """
    generator = np.random.default_rng(seed)
    per_task = [np.asarray(values, dtype=float) for values in scores.values()]
    point = statistic(np.concatenate(per_task))
    resampled = [
        statistic(np.concatenate([values[generator.integers(len(values), size=len(values))] for values in per_task]))
        for _ in range(reps)
    ]
    low, high = np.percentile(resampled, [50 * (1 - confidence), 50 * (1 + confidence)])
    return point, float(low), float(high)


def performance_profile(scores: dict[str, np.ndarray], thresholds: np.ndarray) -> np.ndarray:
    """The fraction of runs whose score exceeds each threshold, each task weighing the same.

    Examples:
        >>> import numpy as np
        >>> from torchrl_mbe.report.intervals import performance_profile
        >>> performance_profile({"a": np.array([0.0, 1.0]), "b": np.array([1.0, 1.0, 1.0, 0.0])}, np.array([0.5]))
        array([0.625])
    """
    thresholds = np.asarray(thresholds, dtype=float)
    per_task = [(np.asarray(values, dtype=float)[:, None] > thresholds[None, :]).mean(0) for values in scores.values()]
    return np.mean(per_task, axis=0)
