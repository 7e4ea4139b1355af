"""Reading run directories (the format of :mod:`torchrl_mbe.rundir`) and grouping runs for the report.

Every directory under ``RUNS_DIR`` (at any depth, so Hydra multirun sweeps work)
that holds a ``summary.json`` is one run. A run directory contains:

- ``summary.json``: ``env``, ``method``, ``seed`` and ``solved_threshold`` (number,
  or null for a task without one) are required; ``frames``, ``episodes``,
  ``wall_time_s`` and ``final_eval_return`` (number or null) are type-checked when
  present, other fields are ignored. Methods named ``explore:<name>`` are
  exploration-only runs, every other method is a learning run.
- ``episodes.csv``: one row per finished training episode, in order, with at
  least the columns ``episode`` (1, 2, ...), ``frames`` (at the episode's end),
  ``return`` and ``reached_goal`` (0/1).
- ``evaluations.csv`` (optional, may be empty): greedy evaluations with at least
  ``frames`` and ``eval_return_mean``; its last row stands in for the final
  evaluation when ``final_eval_return`` is null.
- ``visited_states.npy`` with ``visited_episodes.npy`` (exploration runs,
  optional): every visited observation ``(num_steps, obs_dim)`` and the 1-based
  episode of each.

Runs are grouped by ``(env, method)`` across seeds. The report directory gets
``learning_curves_<env>.png`` (the paper's Figures 2 and 4),
``coverage_<env>.png`` (Figures 1 and 3) and ``results.md``. Runs of DeepSea at
several sizes (envs ``DeepSea-10``, ``DeepSea-20``, ...) are also grouped by method
and size (:func:`deepsea_scaling`) for ``scaling_DeepSea.png``. A malformed file
stops the report with a message naming it: silently dropping a run would hide data.
"""

from __future__ import annotations

import csv
import json
import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from torchrl_mbe.envs.registry import TASKS, EnvBounds, task_of
from torchrl_mbe.report.metrics import EpisodeStats, episode_stats, grid_coverage, loglog_slope
from torchrl_mbe.rundir import EXPLORATION_PREFIX, SUMMARY, SUMMARY_FIELDS, VISITED_EPISODES, VISITED_STATES, table_file

__all__ = [
    "DEEPSEA",
    "Growth",
    "Run",
    "RunFormatError",
    "deepsea_growth",
    "deepsea_scaling",
    "deepsea_size",
    "env_bounds",
    "file_stem",
    "group_runs",
    "load_runs",
    "method_key",
    "plane_coverage",
    "solved_count",
    "solved_threshold",
]

logger = logging.getLogger(__name__)

DEEPSEA = TASKS["deepsea"].env_id
"""DeepSea's env id; a run of size N names its env ``DeepSea-N``."""


class RunFormatError(ValueError):
    """A runs directory that cannot be reported on: missing, without runs, or with a malformed file."""


@dataclass
class Run:
    """One finished run as read from its directory (see the module docstring for the files)."""

    path: Path
    env: str
    method: str
    seed: int
    solved_threshold: float | None
    final_eval_return: float | None
    returns: np.ndarray
    reached_goal: np.ndarray
    visited_states: np.ndarray | None = None
    visited_episodes: np.ndarray | None = None
    tag: str | None = None  # the experiment the run belongs to (summaries of 0.1.0 lack both)
    config_id: str | None = None
    summary: dict = field(default_factory=dict)  # summary.json as written (see torchrl_mbe.rundir.SUMMARY_FIELDS)
    # evaluations.csv: when each greedy evaluation ran
    eval_frames: np.ndarray = field(default_factory=lambda: np.array([]))
    eval_returns: np.ndarray = field(default_factory=lambda: np.array([]))  # and its mean return
    # episodes.csv: frames at each episode's end
    episode_frames: np.ndarray = field(default_factory=lambda: np.array([]))

    @property
    def is_exploration(self) -> bool:
        """Whether this is an exploration-only run (``method`` starts with ``explore:``)."""
        return self.method.startswith(EXPLORATION_PREFIX)

    @property
    def episodes_to_solved(self) -> int | None:
        """Episodes finished by the first solved evaluation (``solved_at_frames``); ``None`` if there was none."""
        solved_at = self.summary.get("solved_at_frames")
        return None if solved_at is None else int((self.episode_frames <= solved_at).sum())

    def stats(self, window: int) -> EpisodeStats:
        """:func:`~torchrl_mbe.report.metrics.episode_stats` of the run's episode table (the goal's running rate for a task solved by success)."""
        solved_by_success = self.summary.get("solved_by") == "success"
        return episode_stats(
            self.reached_goal.astype(float) if solved_by_success else self.returns,
            self.reached_goal,
            self.solved_threshold,
            window=window,
        )


def _read_summary(path: Path) -> dict:
    try:
        summary = json.loads(path.read_text())
    except ValueError as err:  # JSONDecodeError, UnicodeDecodeError
        raise RunFormatError(f"{path}: not valid JSON ({err}).") from None
    if not isinstance(summary, dict):
        raise RunFormatError(f"{path}: expected a JSON object, got {type(summary).__name__}.")
    for name, (check, expected, required) in SUMMARY_FIELDS.items():
        if name not in summary:
            if required:
                raise RunFormatError(f"{path}: missing field {name!r}.")
        elif not check(summary[name]):
            raise RunFormatError(f"{path}: field {name!r} must be {expected}, got {summary[name]!r}.")
    return summary


def _read_csv(path: Path, columns: Sequence[str]) -> dict[str, np.ndarray]:
    """The numeric ``columns`` of a CSV file with a header row; other columns are ignored."""
    values: dict[str, list[float]] = {name: [] for name in columns}
    with path.open(newline="") as file:
        reader = csv.DictReader(file)
        try:
            header = reader.fieldnames or []
            missing = [name for name in columns if name not in header]
            if missing:
                found = ",".join(header) or "(none)"
                raise RunFormatError(f"{path}: header {found} lacks column(s) {', '.join(missing)}.")
            for row in reader:
                for name in columns:
                    values[name].append(_parse_number(row[name], path, reader.line_num, name))
        except (UnicodeDecodeError, csv.Error) as err:
            raise RunFormatError(f"{path}: not a readable CSV file ({err}).") from None
    return {name: np.asarray(column) for name, column in values.items()}


def _parse_number(text: str | None, path: Path, line: int, column: str) -> float:
    if text is None:
        raise RunFormatError(f"{path}: line {line} has no value in column {column!r}.")
    try:
        return float(text)
    except ValueError:
        raise RunFormatError(f"{path}: line {line}, column {column!r}: {text!r} is not a number.") from None


def _read_episodes(path: Path) -> dict[str, np.ndarray]:
    if not path.is_file():
        raise RunFormatError(f"{path}: missing (every run directory needs episodes.csv beside summary.json).")
    table = _read_csv(path, ["episode", "frames", "return", "reached_goal"])
    if not np.array_equal(table["episode"], np.arange(1, len(table["episode"]) + 1)):
        raise RunFormatError(f"{path}: column 'episode' must count 1, 2, 3, ... one row per episode.")
    if not np.isin(table["reached_goal"], (0.0, 1.0)).all():
        raise RunFormatError(f"{path}: column 'reached_goal' must hold only 0 or 1.")
    if not np.isfinite(table["return"]).all():
        raise RunFormatError(f"{path}: column 'return' holds NaN or infinite values.")
    return table


def _read_evaluations(path: Path) -> dict[str, np.ndarray]:
    """The greedy evaluations' frames and mean returns (empty arrays without the file)."""
    if not path.is_file() or path.stat().st_size == 0:
        return {"frames": np.array([]), "eval_return_mean": np.array([])}
    return _read_csv(path, ["frames", "eval_return_mean"])


def _load_array(path: Path) -> np.ndarray:
    try:
        return np.load(path, allow_pickle=False)
    except (OSError, ValueError) as err:
        raise RunFormatError(f"{path}: not a readable .npy array ({err}).") from None


def _read_visited(run_dir: Path) -> tuple[np.ndarray | None, np.ndarray | None]:
    states_path, episodes_path = run_dir / VISITED_STATES, run_dir / VISITED_EPISODES
    if not states_path.is_file():
        return None, None
    if not episodes_path.is_file():
        raise RunFormatError(f"{episodes_path}: missing (visited_states.npy needs it beside it).")
    states, episodes = _load_array(states_path), _load_array(episodes_path)
    if states.ndim != 2 or not np.issubdtype(states.dtype, np.number) or not np.isfinite(states).all():
        raise RunFormatError(
            f"{states_path}: expected finite numbers of shape (num_steps, obs_dim), got {states.dtype} {states.shape}."
        )
    if episodes.shape != (len(states),) or not np.issubdtype(episodes.dtype, np.integer):
        raise RunFormatError(
            f"{episodes_path}: expected integers of shape ({len(states)},) to match visited_states.npy, "
            f"got {episodes.dtype} {episodes.shape}."
        )
    if len(states) == 0:
        logger.warning("%s is empty; the run counts as one without visited states.", states_path)
        return None, None
    return states, episodes


def _read_run(run_dir: Path) -> Run:
    summary = _read_summary(run_dir / SUMMARY)
    episodes = _read_episodes(run_dir / table_file("episodes"))
    evaluations = _read_evaluations(run_dir / table_file("evaluations"))
    final_eval = summary.get("final_eval_return")
    if final_eval is None and len(evaluations["eval_return_mean"]):
        final_eval = evaluations["eval_return_mean"][-1]
    states, visited_episodes = _read_visited(run_dir)
    return Run(
        path=run_dir,
        env=summary["env"],
        method=summary["method"],
        seed=summary["seed"],
        solved_threshold=summary["solved_threshold"],
        final_eval_return=None if final_eval is None else float(final_eval),
        returns=episodes["return"],
        reached_goal=episodes["reached_goal"].astype(bool),
        visited_states=states,
        visited_episodes=visited_episodes,
        tag=summary.get("tag"),
        config_id=summary.get("config_id"),
        summary=summary,
        eval_frames=evaluations["frames"],
        eval_returns=evaluations["eval_return_mean"],
        episode_frames=episodes["frames"],
    )


def load_runs(runs_dir: str | Path) -> list[Run]:
    """Every run under ``runs_dir`` (any directory holding a ``summary.json``, at any depth).

    Raises:
        RunFormatError: if ``runs_dir`` is missing, holds no run, or a run's file is malformed.

    Examples:
        >>> load_runs("/no/such/dir")
        Traceback (most recent call last):
        ...
        torchrl_mbe.report.runs.RunFormatError: runs directory /no/such/dir does not exist.
    """
    runs_dir = Path(runs_dir)
    if not runs_dir.is_dir():
        raise RunFormatError(f"runs directory {runs_dir} does not exist.")
    runs = [_read_run(summary.parent) for summary in sorted(runs_dir.rglob(SUMMARY))]
    if not runs:
        raise RunFormatError(f"no runs under {runs_dir}: no summary.json found at any depth.")
    seen: dict[tuple[str, str, int], Path] = {}
    for run in runs:
        key = (run.env, run.method, run.seed)
        if key in seen:
            logger.warning("%s and %s are both %s seed %d; both count.", seen[key], run.path, run.method, run.seed)
        seen[key] = run.path
    logger.info("Read %d runs from %s.", len(runs), runs_dir)
    return runs


def file_stem(env: str) -> str:
    return env.replace("/", "_")


def method_key(method: str) -> tuple[int, str]:
    """Exploration-only methods (``explore:...``) first, then an algorithm with an explorer (``dqn+...``), then the rest; by name within each.

    Examples:
        >>> from torchrl_mbe.report.runs import method_key
        >>> sorted(["reinforce", "dqn+noisy", "explore:random", "dqn+diagonal"], key=method_key)
        ['explore:random', 'dqn+diagonal', 'dqn+noisy', 'reinforce']
    """
    kind = 0 if method.startswith(EXPLORATION_PREFIX) else 1 if "+" in method else 2
    return kind, method


def group_runs(runs: Sequence[Run]) -> dict[str, list[Run]]:
    """Runs of one experiment per group, in :func:`method_key` order, each group's runs sorted by seed.

    An experiment is a method run with one config (``tag`` and ``config_id``); the
    group is labelled by its method, or ``method [tag config_id]`` when the method
    was run with several configs, so that runs of different configs never merge.
    """
    configs: dict[str, set] = {}
    for run in runs:
        configs.setdefault(run.method, set()).add((run.tag, run.config_id))
    groups: dict[str, list[Run]] = {}
    for run in sorted(runs, key=lambda r: (method_key(r.method), r.tag or "", r.config_id or "", r.seed)):
        label = run.method if len(configs[run.method]) == 1 else f"{run.method} [{run.tag} {run.config_id}]"
        groups.setdefault(label, []).append(run)
    return groups


def deepsea_size(env: str) -> int | None:
    """The N of a DeepSea run's env (``DeepSea-20`` -> 20); ``None`` for any other env.

    Examples:
        >>> from torchrl_mbe.report.runs import deepsea_size
        >>> deepsea_size("DeepSea-20"), deepsea_size("DeepSea"), deepsea_size("MountainCar-v0")
        (20, None, None)
    """
    name, _, size = env.rpartition("-")
    return int(size) if name == DEEPSEA and size.isdigit() else None


def deepsea_scaling(runs: Sequence[Run]) -> dict[str, dict[int, list[Run]]]:
    """DeepSea's learning runs by series and size N, sizes ascending; empty unless two or more sizes were run.

    A series is a method run with one preset (``tag``) at every size, labelled by the method,
    or ``method [tag]`` where the method ran with several presets: each size has a config of its
    own, so :func:`group_runs`' ``config_id`` cannot join sizes. Where one series holds several
    configs at one size, that size's runs are split by :func:`group_runs`' labels instead.
    """
    by_size: dict[int, list[Run]] = {}
    for run in runs:
        size = deepsea_size(run.env)
        if size is not None and not run.is_exploration:
            by_size.setdefault(size, []).append(run)
    if len(by_size) < 2:
        return {}
    tags: dict[str, set] = {}
    for run in (run for size_runs in by_size.values() for run in size_runs):
        tags.setdefault(run.method, set()).add(run.tag)
    scaling: dict[str, dict[int, list[Run]]] = {}
    for size in sorted(by_size):
        groups = group_runs(by_size[size])
        series = {
            label: group[0].method if len(tags[group[0].method]) == 1 else f"{group[0].method} [{group[0].tag}]"
            for label, group in groups.items()
        }
        for label, group in groups.items():
            one_config = list(series.values()).count(series[label]) == 1
            scaling.setdefault(series[label] if one_config else label, {})[size] = group
    return dict(sorted(scaling.items(), key=lambda item: method_key(item[0])))


@dataclass(frozen=True)
class Growth:
    """How a method's episodes to solved grow with DeepSea's size: about ``N ** exponent``, fitted on ``sizes``."""

    exponent: float
    sizes: tuple[int, ...]


def deepsea_growth(episodes_by_size: dict[int, list[int | None]]) -> Growth | None:
    """The log-log slope against N of the median episodes (to solved, or to the first treasure) over the seeds that got there.

    ``episodes_by_size[N]`` holds each seed's episodes at size N, ``None`` for a seed
    that never got there. Fitted over the sizes where at least half of the seeds got
    there, so that a size that one lucky seed reached does not bend the line; ``None``
    where fewer than two sizes qualify.

    Examples:
        >>> from torchrl_mbe.report.runs import deepsea_growth
        >>> growth = deepsea_growth({10: [100, 100, None], 20: [400, 400], 30: [None, None, 5]})
        >>> round(growth.exponent, 2), growth.sizes
        (2.0, (10, 20))
    """
    medians = {}
    for size, episodes in episodes_by_size.items():
        reached = [episode for episode in episodes if episode is not None]
        if reached and 2 * len(reached) >= len(episodes):
            medians[size] = float(np.median(reached))
    exponent = loglog_slope(list(medians), list(medians.values()))
    return None if exponent is None else Growth(exponent, tuple(medians))


def env_bounds(env: str, runs: Sequence[Run]) -> tuple[EnvBounds | None, bool]:
    """The coverage box of ``env`` and whether it was fitted to the data.

    The registry's box (``Task.bounds``) if there is one, else bounds fitted to all the
    env's visited states, else ``None``.
    """
    task = task_of(env)
    if task is not None:
        return task.bounds, False
    states = [r.visited_states for r in runs if r.visited_states is not None]
    return (EnvBounds.from_states(np.concatenate(states)), True) if states else (None, False)


def solved_threshold(groups: dict[str, list[Run]]) -> float | None:
    """The env's solved threshold, as its first run recorded it."""
    return next(iter(groups.values()))[0].solved_threshold


def solved_count(runs: Sequence[Run]) -> str:
    """``"n/N"``: how many of the runs' summaries say ``solved``."""
    return f"{sum(run.summary.get('solved') is True for run in runs)}/{len(runs)}"


def plane_coverage(run: Run, bounds: EnvBounds, bins: int, *, first: int | None = None) -> float:
    """Grid coverage of the run's visited states (its ``first`` ones only, if given) on the env's plane."""
    states = run.visited_states[:first]
    return grid_coverage(states, bounds.plane_low, bounds.plane_high, bins, dims=bounds.plane)
