"""The explorers compared across tasks: interquartile means with stratified bootstrap 95% intervals, and performance profiles.

Two scores per run, each on a scale shared by every task:

* the **normalized score**: the final greedy return, ``0`` at the lowest return of any episode
  (training or final evaluation) of any run of that task and ``1`` at its solved threshold (a success-rate task, MiniGrid's,
  scores its success rate); higher is better;
* the **fraction of the budget to solved**: frames to the first solved evaluation over the
  task's longest run (a run that never solved counts ``1``); lower is better.

Only tasks with a solved threshold and methods that ran on at least two of them are compared.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TypeVar

import numpy as np

from torchrl_mbe.report.intervals import iqm, stratified_bootstrap_ci
from torchrl_mbe.report.runs import Run

__all__ = ["across_tasks_rows", "budget_fractions", "iqm_interval", "normalized_scores"]

T = TypeVar("T")


def normalized_scores(runs: Sequence[Run]) -> dict[str, dict[str, np.ndarray]]:
    """``{method: {task: each seed's normalized score}}`` of the runs with a final evaluation."""
    scores: dict[str, dict[str, list[float]]] = {}
    for task, task_runs in _by_task(runs, lambda run: run.summary).items():
        low = min(min(run.final_eval_return, *run.returns) for run in task_runs)
        threshold = task_runs[0].solved_threshold
        for run in task_runs:
            if run.summary.get("solved_by") == "success":
                score = run.summary["final_eval_success_rate"]
            else:
                score = (run.final_eval_return - low) / max(threshold - low, 1e-9)
            scores.setdefault(run.method, {}).setdefault(task, []).append(score)
    return _compared(scores)


def budget_fractions(summaries: Sequence[dict]) -> dict[str, dict[str, np.ndarray]]:
    """``{method: {task: each seed's frames to solved over the task's longest run}}`` (1 for a run that never solved), from the runs' summaries.

    Examples:
        >>> from torchrl_mbe.report.across import budget_fractions
        >>> def summary(env, method, solved_at, frames):
        ...     return {"env": env, "method": method, "solved_threshold": 1.0, "final_eval_return": 0.0,
        ...             "solved_at_frames": solved_at, "frames": frames}
        >>> runs = [summary(env, "dqn+gaussian", 500, 500) for env in ("A", "B")]
        >>> runs += [summary(env, "dqn+egreedy", None, 1000) for env in ("A", "B")]
        >>> {method: {task: v.tolist() for task, v in tasks.items()} for method, tasks in budget_fractions(runs).items()}
        {'dqn+egreedy': {'A': [1.0], 'B': [1.0]}, 'dqn+gaussian': {'A': [0.5], 'B': [0.5]}}
    """
    fractions: dict[str, dict[str, list[float]]] = {}
    for task, task_summaries in _by_task(summaries, lambda summary: summary).items():
        budget = max(summary.get("frames", 0) for summary in task_summaries) or 1
        for summary in task_summaries:
            solved_at = summary.get("solved_at_frames")
            fractions.setdefault(summary["method"], {}).setdefault(task, []).append(
                1.0 if solved_at is None else solved_at / budget
            )
    return _compared(fractions)


def _by_task(runs: Sequence[T], summary_of: Callable[[T], dict]) -> dict[str, list[T]]:
    """The runs whose summary has a solved threshold and a final evaluation, by task."""
    tasks: dict[str, list[T]] = {}
    for run in runs:
        summary = summary_of(run)
        if summary.get("solved_threshold") is not None and summary.get("final_eval_return") is not None:
            tasks.setdefault(summary["env"], []).append(run)
    return tasks


def _compared(values: dict[str, dict[str, list[float]]]) -> dict[str, dict[str, np.ndarray]]:
    """The methods that ran on at least two tasks, each task's values as an array."""
    return {
        method: {task: np.asarray(seeds) for task, seeds in sorted(tasks.items())}
        for method, tasks in sorted(values.items())
        if len(tasks) >= 2
    }


def across_tasks_rows(runs: Sequence[Run]) -> tuple[list[list[str]], dict[str, dict[str, np.ndarray]]]:
    """One row per compared method (method, tasks, runs, both IQMs with their intervals), and the normalized scores."""
    scores, fractions = normalized_scores(runs), budget_fractions([run.summary for run in runs])
    rows = [
        [
            method,
            ", ".join(per_task),
            str(sum(len(seeds) for seeds in per_task.values())),
            iqm_interval(per_task),
            iqm_interval(fractions[method]),
        ]
        for method, per_task in scores.items()
    ]
    return rows, scores


def iqm_interval(per_task: dict[str, np.ndarray]) -> str:
    """The interquartile mean of the values pooled over tasks and its stratified bootstrap 95% interval, as ``IQM [low, high]``.

    Examples:
        >>> import numpy as np
        >>> from torchrl_mbe.report.across import iqm_interval
        >>> iqm_interval({"A": np.array([0.5, 0.5]), "B": np.array([0.5])})
        '0.50 [0.50, 0.50]'
    """
    point, low, high = stratified_bootstrap_ci(per_task, iqm)
    return f"{point:.2f} [{low:.2f}, {high:.2f}]"
