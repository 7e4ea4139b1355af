"""The run directory: what a training run writes and the report reads.

One owner for the format, used by both sides (:mod:`torchrl_mbe.app` writes,
:mod:`torchrl_mbe.report` reads); it imports nothing but the standard library.

A run directory holds:

* ``summary.json``: the run's outcome, fields in :data:`SUMMARY_FIELDS`;
* the CSV tables of :func:`tables` (``episodes.csv``: one row per finished training
  episode; ``evaluations.csv``: one row per greedy evaluation; ``updates.csv``:
  losses, dynamics error, eps and throughput every few updates);
* ``checkpoint.pt`` (what ``resume=true`` continues from) and ``best_policy.pt``
  (the greedy actor of the best periodic evaluation);
* ``visited_states.npy`` with ``visited_episodes.npy`` when the run records the
  states it visited (the coverage experiment).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

__all__ = [
    "BEST_POLICY",
    "CHECKPOINT",
    "EXPLORATION_PREFIX",
    "SUMMARY",
    "SUMMARY_FIELDS",
    "UPDATE_COUNTERS",
    "VISITED_EPISODES",
    "VISITED_STATES",
    "is_int",
    "is_number",
    "table_file",
    "tables",
]

SUMMARY = "summary.json"
CHECKPOINT = "checkpoint.pt"
BEST_POLICY = "best_policy.pt"
VISITED_STATES = "visited_states.npy"
VISITED_EPISODES = "visited_episodes.npy"


def tables(explorer_columns: Sequence[str] = ()) -> dict[str, tuple[str, ...]]:
    """The CSV tables of a run and their columns; ``explorer_columns``: what explorers log beside the Q loss.

    The app passes the columns its explorers declare (``Explorer.log_columns``, in
    :mod:`torchrl_mbe.app.explorers`), every one in every run, so all runs share one header.

    Examples:
        >>> from torchrl_mbe.rundir import tables
        >>> tables(["loss_rnd"])["updates"]
        ('frames', 'updates', 'loss_q', 'loss_rnd', 'eps', 'frames_per_s')
    """
    return {
        "episodes": ("episode", "frames", "return", "length", "reached_goal", "eps", "wall_time_s"),
        "evaluations": ("frames", "episode", "eval_return_mean", "eval_return_std", "eval_success_rate"),
        "updates": ("frames", "updates", "loss_q", *explorer_columns, "eps", "frames_per_s"),
    }


UPDATE_COUNTERS = ("q_updates",)
"""The summary's update counters every DQN run has; explorers declare theirs (``Explorer.counters``)."""
"""The summary's counts of gradient updates, per model; 0 for a model the algorithm does not have."""

EXPLORATION_PREFIX = "explore:"
"""Methods named ``explore:<explorer>`` are exploration-only runs (the Q-network never learns)."""


def table_file(table: str) -> str:
    """The file name of one of the :func:`tables`: ``episodes.csv``, ..."""
    return f"{table}.csv"


def is_number(value: Any) -> bool:
    """Whether ``value`` is an int or float (a bool is neither), as JSON and YAML numbers are read."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def is_int(value: Any) -> bool:
    """Whether ``value`` is an int (a bool is not)."""
    return isinstance(value, int) and not isinstance(value, bool)


def _optional(test: Callable[[Any], bool]) -> Callable[[Any], bool]:
    return lambda value: value is None or test(value)


def _text(value: Any) -> bool:
    return isinstance(value, str) and bool(value)


SUMMARY_FIELDS: dict[str, tuple[Callable[[Any], bool], str, bool]] = {
    # name: (check, what it must be, required by the report)
    "env": (_text, "a non-empty string", True),
    "method": (_text, "a non-empty string", True),
    "seed": (is_int, "an integer", True),
    "solved_threshold": (_optional(is_number), "a number or null", True),
    "tag": (_text, "a non-empty string", False),
    "config_id": (_text, "a non-empty string", False),
    "frames": (is_int, "an integer", False),
    "episodes": (is_int, "an integer", False),
    "q_updates": (is_int, "an integer", False),
    "dynamics_updates": (is_int, "an integer", False),
    "wall_time_s": (is_number, "a number", False),
    "frames_per_s": (is_number, "a number", False),
    "first_success_episode": (_optional(is_int), "an integer or null", False),
    "final_eval_return": (_optional(is_number), "a number or null", False),
    "final_eval_success_rate": (_optional(is_number), "a number or null", False),
    "best_eval_return": (_optional(is_number), "a number or null", False),
    "best_eval_frames": (_optional(is_int), "an integer or null", False),
    "solved_by": (lambda v: v in ("return", "success"), "return or success", False),
    "solved": (_optional(lambda v: isinstance(v, bool)), "true, false or null", False),
    "solved_at_frames": (_optional(is_int), "an integer or null", False),
    "solved_at_wall_time_s": (_optional(is_number), "a number or null", False),
    "record": (lambda v: isinstance(v, dict), "an object (commit, cpu, cores, device, versions, command)", False),
}
"""Every field of ``summary.json``. ``tag`` and ``config_id`` (a fingerprint of every
setting that shapes the result except the seed) say which experiment a run belongs
to, so the report groups only runs of the same config; ``solved`` compares the
final evaluation with the threshold (``solved_by``: its mean ``return``, or its
``success`` rate, MiniGrid's rule); ``solved_at_*`` is the first periodic
evaluation at or above it that an evaluation of ``eval.final_episodes`` episodes
confirmed; ``record`` says where the result comes from (the code's commit, the machine,
the library versions and the command)."""
