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

from collections.abc import Sequence

import numpy as np

from torchrl_mbe.report.intervals import iqm, stratified_bootstrap_ci
from torchrl_mbe.report.runs import Run

__all__ = ["across_tasks_rows", "budget_fractions", "normalized_scores"]


def normalized_scores(runs: Sequence[Run]) -> dict[str, dict[str, np.ndarray]]:
    """``{method: {task: each seed's normalized score}}`` of the runs with a final evaluation."""
    scores: dict[str, dict[str, list[float]]] = {}
    for task, task_runs in _by_task(runs).items():
        low = min(min(run.final_eval_return, *run.returns) for run in task_runs)
        threshold = task_runs[0].solved_threshold
        for run in task_runs:
            if run.summary.get("solved_by") == "success":
                score = run.summary["final_eval_success_rate"]
            else:
                score = (run.final_eval_return - low) / max(threshold - low, 1e-9)
            scores.setdefault(run.method, {}).setdefault(task, []).append(score)
    return _compared(scores)


def budget_fractions(runs: Sequence[Run]) -> dict[str, dict[str, np.ndarray]]:
    """``{method: {task: each seed's frames to solved over the task's longest run}}`` (1 for a run that never solved)."""
    fractions: dict[str, dict[str, list[float]]] = {}
    for task, task_runs in _by_task(runs).items():
        budget = max(run.summary.get("frames", 0) for run in task_runs) or 1
        for run in task_runs:
            solved_at = run.summary.get("solved_at_frames")
            fractions.setdefault(run.method, {}).setdefault(task, []).append(
                1.0 if solved_at is None else solved_at / budget
            )
    return _compared(fractions)


def _by_task(runs: Sequence[Run]) -> dict[str, list[Run]]:
    judged = [r for r in runs if r.solved_threshold is not None and r.final_eval_return is not None]
    tasks: dict[str, list[Run]] = {}
    for run in judged:
        tasks.setdefault(run.env, []).append(run)
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
    scores, fractions = normalized_scores(runs), budget_fractions(runs)
    rows = [
        [
            method,
            ", ".join(per_task),
            str(sum(len(seeds) for seeds in per_task.values())),
            _interval(per_task),
            _interval(fractions[method]),
        ]
        for method, per_task in scores.items()
    ]
    return rows, scores


def _interval(per_task: dict[str, np.ndarray]) -> str:
    point, low, high = stratified_bootstrap_ci(per_task, iqm)
    return f"{point:.2f} [{low:.2f}, {high:.2f}]"
