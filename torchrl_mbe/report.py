"""Figures and tables from finished runs: ``python -m torchrl_mbe.report RUNS_DIR [--out OUT_DIR]``.

Every directory under ``RUNS_DIR`` (at any depth, so Hydra multirun sweeps work)
that holds a ``summary.json`` is one run. A run directory contains:

- ``summary.json``: ``env``, ``method``, ``seed`` and ``solved_threshold`` (number,
  or null for a task without one) are required; ``frames``, ``episodes``,
  ``wall_time_s`` and ``final_eval_return`` (number or null) are type-checked when
  present, other fields are ignored. Methods named ``explore:<name>`` are
  exploration-only runs, every other method is a learning run.
- ``episodes.csv``: one row per finished training episode, in order, with at
  least the columns ``episode`` (1, 2, ...), ``return`` and ``reached_goal`` (0/1).
- ``evaluations.csv`` (optional, may be empty): greedy evaluations with at least
  ``frames`` and ``eval_return_mean``; its last row stands in for the final
  evaluation when ``final_eval_return`` is null.
- ``visited_states.npy`` with ``visited_episodes.npy`` (exploration runs,
  optional): every visited observation ``(num_steps, obs_dim)`` and the 1-based
  episode of each.

Runs are grouped by ``(env, method)`` across seeds. The report directory gets
``learning_curves_<env>.png`` (the paper's Figures 2 and 4),
``coverage_<env>.png`` (Figures 1 and 3) and ``results.md``. A malformed file
stops the report with a message naming it: silently dropping a run would hide data.
"""
from __future__ import annotations

import argparse
import csv
import json
import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from torchrl_mbe.metrics import ENV_BOUNDS, EnvBounds, EpisodeStats, episode_stats, grid_coverage, max_position
from torchrl_mbe.metrics import pairwise_coverage, running_average

__all__ = ["RunFormatError", "Run", "load_runs", "write_report", "main"]

logger = logging.getLogger(__name__)

_EXPLORATION_PREFIX = "explore:"
_MISSING = "–"


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

    @property
    def is_exploration(self) -> bool:
        """Whether this is an exploration-only run (``method`` starts with ``explore:``)."""
        return self.method.startswith(_EXPLORATION_PREFIX)

    def stats(self, window: int) -> EpisodeStats:
        """:func:`~torchrl_mbe.metrics.episode_stats` of the run's episode table."""
        return episode_stats(self.returns, self.reached_goal, self.solved_threshold, window=window)


# ----------------------------------------------------------------------------- reading


def _is_number(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


_SUMMARY_FIELDS: dict[str, tuple[Callable[[object], bool], str, bool]] = {
    # name: (check, what it must be, required)
    "env": (lambda v: isinstance(v, str) and bool(v), "a non-empty string", True),
    "method": (lambda v: isinstance(v, str) and bool(v), "a non-empty string", True),
    "seed": (_is_int, "an integer", True),
    "solved_threshold": (lambda v: v is None or _is_number(v), "a number or null", True),
    "frames": (_is_int, "an integer", False),
    "episodes": (_is_int, "an integer", False),
    "wall_time_s": (_is_number, "a number", False),
    "final_eval_return": (lambda v: v is None or _is_number(v), "a number or null", False),
}


def _read_summary(path: Path) -> dict:
    try:
        summary = json.loads(path.read_text())
    except ValueError as err:  # JSONDecodeError, UnicodeDecodeError
        raise RunFormatError(f"{path}: not valid JSON ({err}).") from None
    if not isinstance(summary, dict):
        raise RunFormatError(f"{path}: expected a JSON object, got {type(summary).__name__}.")
    for name, (check, expected, required) in _SUMMARY_FIELDS.items():
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
    table = _read_csv(path, ["episode", "return", "reached_goal"])
    if not np.array_equal(table["episode"], np.arange(1, len(table["episode"]) + 1)):
        raise RunFormatError(f"{path}: column 'episode' must count 1, 2, 3, ... one row per episode.")
    if not np.isin(table["reached_goal"], (0.0, 1.0)).all():
        raise RunFormatError(f"{path}: column 'reached_goal' must hold only 0 or 1.")
    if not np.isfinite(table["return"]).all():
        raise RunFormatError(f"{path}: column 'return' holds NaN or infinite values.")
    return table


def _last_evaluation(path: Path) -> float | None:
    if not path.is_file() or path.stat().st_size == 0:
        return None
    means = _read_csv(path, ["frames", "eval_return_mean"])["eval_return_mean"]
    return float(means[-1]) if len(means) else None


def _load_array(path: Path) -> np.ndarray:
    try:
        return np.load(path, allow_pickle=False)
    except (OSError, ValueError) as err:
        raise RunFormatError(f"{path}: not a readable .npy array ({err}).") from None


def _read_visited(run_dir: Path) -> tuple[np.ndarray | None, np.ndarray | None]:
    states_path, episodes_path = run_dir / "visited_states.npy", run_dir / "visited_episodes.npy"
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
    summary = _read_summary(run_dir / "summary.json")
    episodes = _read_episodes(run_dir / "episodes.csv")
    final_eval = summary.get("final_eval_return")
    if final_eval is None:
        final_eval = _last_evaluation(run_dir / "evaluations.csv")
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
    )


def load_runs(runs_dir: str | Path) -> list[Run]:
    """Every run under ``runs_dir`` (any directory holding a ``summary.json``, at any depth).

    Raises:
        RunFormatError: if ``runs_dir`` is missing, holds no run, or a run's file is malformed.

    Examples:
        >>> load_runs("/no/such/dir")
        Traceback (most recent call last):
        ...
        torchrl_mbe.report.RunFormatError: runs directory /no/such/dir does not exist.
    """
    runs_dir = Path(runs_dir)
    if not runs_dir.is_dir():
        raise RunFormatError(f"runs directory {runs_dir} does not exist.")
    runs = [_read_run(summary.parent) for summary in sorted(runs_dir.rglob("summary.json"))]
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


# ----------------------------------------------------------------------------- formatting


def _fmt(value: float | None, digits: int = 1) -> str:
    if value is None:
        return _MISSING
    return str(value) if isinstance(value, int) else f"{value:.{digits}f}"


def _mean_and_seeds(values: Sequence[float | None], digits: int = 1) -> str:
    """``mean [per seed]``; the mean is over the seeds that have a value."""
    present = [v for v in values if v is not None]
    mean = _fmt(float(np.mean(present)), digits) if present else _MISSING
    return f"{mean} [{', '.join(_fmt(v, digits) for v in values)}]"


def _percent_and_seeds(fractions: Sequence[float]) -> str:
    """``mean ± std [per seed]`` of fractions, in percent; ``–`` for none."""
    if not fractions:
        return _MISSING
    percent = 100.0 * np.asarray(fractions)
    per_seed = ", ".join(f"{v:.1f}%" for v in percent)
    return f"{percent.mean():.1f}% ± {percent.std():.1f}% [{per_seed}]"


def _table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return lines + ["| " + " | ".join(row) + " |" for row in rows]


def _file_stem(env: str) -> str:
    return env.replace("/", "_")


_METHOD_ORDER = (
    "explore:random", "explore:kernel", "explore:gaussian", "explore:oracle",
    "dqn+gaussian", "dqn+kernel", "dqn+egreedy", "dqn+none", "reinforce",
)
"""Methods in the paper's order (baselines beside the proposal); others follow alphabetically."""


def _method_key(method: str) -> tuple[int, str]:
    return (_METHOD_ORDER.index(method) if method in _METHOD_ORDER else len(_METHOD_ORDER), method)


def _group(runs: Sequence[Run]) -> dict[str, list[Run]]:
    """Runs by method in :data:`_METHOD_ORDER`, each method's runs sorted by seed."""
    groups: dict[str, list[Run]] = {}
    for run in sorted(runs, key=lambda r: (_method_key(r.method), r.seed)):
        groups.setdefault(run.method, []).append(run)
    return groups


def _env_bounds(env: str, runs: Sequence[Run]) -> tuple[EnvBounds | None, bool]:
    """The coverage box of ``env`` and whether it was fitted to the data.

    The :data:`ENV_BOUNDS` entry if there is one, else bounds fitted to all the
    env's visited states, else ``None``.
    """
    if env in ENV_BOUNDS:
        return ENV_BOUNDS[env], False
    states = [r.visited_states for r in runs if r.visited_states is not None]
    return (EnvBounds.from_states(np.concatenate(states)), True) if states else (None, False)


def _solved_threshold(groups: dict[str, list[Run]]) -> float | None:
    """The env's solved threshold, as its first run recorded it."""
    return next(iter(groups.values()))[0].solved_threshold


def _plane_coverage(run: Run, bounds: EnvBounds, bins: int) -> float:
    return grid_coverage(run.visited_states, bounds.plane_low, bounds.plane_high, bins, dims=bounds.plane)


# ----------------------------------------------------------------------------- figures


def _save(fig: Figure, path: Path) -> Path:
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=120)
    return path


def _plot_learning_curves(
    env: str, groups: dict[str, list[Run]], colors: dict[str, str], window: int, path: Path
) -> Path | None:
    """Running average return per episode, mean over seeds with a min-max band; ``None`` if no run has episodes."""
    fig = Figure(figsize=(8, 5), layout="constrained")
    ax = fig.add_subplot()
    plotted = False
    for method, runs in groups.items():
        curves = [running_average(r.returns, window) for r in runs if len(r.returns)]
        if not curves:
            continue
        length = min(len(c) for c in curves)
        if length < max(len(c) for c in curves):
            logger.info("%s %s: curve cut to the shortest seed's %d episodes.", env, method, length)
        stacked = np.stack([c[:length] for c in curves])
        episodes = np.arange(1, length + 1)
        label = f"{method} ({len(curves)} seed{'s' * (len(curves) > 1)})"
        ax.plot(episodes, stacked.mean(0), color=colors[method], label=label)
        ax.fill_between(episodes, stacked.min(0), stacked.max(0), color=colors[method], alpha=0.2, linewidth=0)
        plotted = True
    if not plotted:
        return None
    threshold = _solved_threshold(groups)
    if threshold is not None:
        ax.axhline(threshold, color="0.3", linestyle="--", linewidth=1, label=f"solved ({threshold:g})")
    ax.set_xlabel("training episode")
    ax.set_ylabel(f"return, running average of last {window} episodes")
    ax.set_title(f"{env}: learning curves (line: mean over seeds, band: min to max)")
    ax.grid(alpha=0.3)
    ax.legend(loc="best")
    return _save(fig, path)


def _plot_coverage(env: str, best: dict[str, tuple[Run, float, int]], bounds: EnvBounds, bins: int, path: Path) -> Path:
    """One scatter panel per method, of its best-covering run: ``best[method] = (run, coverage, num_seeds)``."""
    x_dim, y_dim = bounds.plane
    fig = Figure(figsize=(4.2 * len(best) + 1.0, 4.4), layout="constrained")
    axes = fig.subplots(1, len(best), squeeze=False, sharex=True, sharey=True)[0]
    norm = Normalize(1, max(int(run.visited_episodes.max(initial=1)) for run, _, _ in best.values()))
    scatter = None
    for ax, (method, (run, coverage, num_seeds)) in zip(axes, best.items()):
        states = run.visited_states
        scatter = ax.scatter(
            states[:, x_dim], states[:, y_dim], c=run.visited_episodes, cmap="viridis", norm=norm,
            s=2, linewidths=0, rasterized=True,
        )
        ax.set_title(f"{method}\ncoverage {coverage:.1%} (seed {run.seed}, best of {num_seeds})", fontsize=10)
        ax.set_xlabel(bounds.labels[x_dim])
        ax.grid(alpha=0.3)
    axes[0].set_ylabel(bounds.labels[y_dim])
    all_states = np.concatenate([run.visited_states for run, _, _ in best.values()])
    for set_lim, dim in ((axes[0].set_xlim, x_dim), (axes[0].set_ylim, y_dim)):
        set_lim(min(bounds.low[dim], all_states[:, dim].min()), max(bounds.high[dim], all_states[:, dim].max()))
    fig.colorbar(scatter, ax=list(axes), label="episode", ticks=MaxNLocator(integer=True))
    fig.suptitle(f"{env}: visited states ({bins}x{bins} grid coverage)")
    return _save(fig, path)


# ----------------------------------------------------------------------------- tables


def _learning_section(groups: dict[str, list[Run]], window: int) -> list[str]:
    threshold = _solved_threshold(groups)
    solved_at = "no solved threshold" if threshold is None else f"solved at a {window}-episode average of {threshold:g}"
    rows = []
    for method, runs in groups.items():
        stats = [r.stats(window) for r in runs]
        solved = [s.solved_episode for s in stats]
        num_solved = sum(e is not None for e in solved)
        rows.append(
            [
                method,
                ", ".join(str(r.seed) for r in runs),
                _mean_and_seeds([s.num_episodes for s in stats]),
                _mean_and_seeds([s.first_success_episode for s in stats]),
                _mean_and_seeds([s.num_successes for s in stats]),
                _mean_and_seeds([s.best_running_average for s in stats]),
                _mean_and_seeds([s.final_running_average for s in stats]),
                _mean_and_seeds([r.final_eval_return for r in runs]),
                f"{num_solved}/{len(runs)} at [{', '.join(_fmt(e) for e in solved)}]",
            ]
        )
    header = [
        "method", "seeds", "episodes", "first success episode", "successful episodes",
        f"best {window}-ep avg", f"final {window}-ep avg", "final greedy eval", "solved (episode)",
    ]
    return [f"### Learning ({solved_at})", "", *_table(header, rows), ""]


def _exploration_section(
    groups: dict[str, list[Run]], bounds: EnvBounds | None, fitted: bool, window: int, bins: int
) -> list[str]:
    """The exploration table; coverage columns only when the env has bounds (see :func:`_env_bounds`)."""
    header = ["method", "seeds", "episodes", "episodes reaching goal", "first success episode"]
    pair_dims = bounds.coverage_dims if bounds is not None and len(bounds.coverage_dims) > 2 else ()
    if bounds is not None:
        header.append("coverage " + " x ".join(bounds.labels[d] for d in bounds.plane))
        if pair_dims:
            header.append(f"coverage, mean over pairs of {len(pair_dims)} dims")
        if bounds.progress_dim is not None:
            header.append(f"max {bounds.labels[bounds.progress_dim]}")
    rows = []
    for method, runs in groups.items():
        stats = [r.stats(window) for r in runs]
        row = [
            method,
            ", ".join(str(r.seed) for r in runs),
            _mean_and_seeds([s.num_episodes for s in stats]),
            _mean_and_seeds([s.num_successes for s in stats]),
            _mean_and_seeds([s.first_success_episode for s in stats]),
        ]
        with_states = [r for r in runs if r.visited_states is not None]
        if bounds is not None:
            row.append(_percent_and_seeds([_plane_coverage(r, bounds, bins) for r in with_states]))
            if pair_dims:
                row.append(_percent_and_seeds([pairwise_coverage(r.visited_states, bounds, bins) for r in with_states]))
            if bounds.progress_dim is not None:
                row.append(_mean_and_seeds([max_position(r.visited_states, bounds.progress_dim) for r in with_states], 3))
        rows.append(row)
    lines = ["### Exploration", "", *_table(header, rows), ""]
    if bounds is not None:
        box = ", ".join(
            f"{bounds.labels[d]} in [{bounds.low[d]:.3g}, {bounds.high[d]:.3g}]" for d in bounds.coverage_dims
        )
        source = "fitted to this environment's visited states: it has no entry in ENV_BOUNDS" if fitted else "fixed"
        lines += [
            f"Coverage: fraction of the cells of a {bins}x{bins} grid holding a visited state; box ({source}): {box}. "
            "Coverage and max values are over the seeds that saved visited states.",
            "",
        ]
    return lines


_DEFINITIONS = """\
## How to read these tables

- `mean [per seed]`: the mean is over the seeds that have a value; `–` means none
  (never reached the goal, never solved, no evaluation).
- Running average at episode i: mean return of episodes max(1, i-{w}+1) .. i, so curves
  start at episode 1. *Best* average only counts windows of {w} episodes (all of them
  if the run is shorter); *final* is the last {w} episodes.
- Solved: first episode at which the mean of the last full {w} episodes reached the
  threshold (gymnasium's definition; a run shorter than {w} episodes is never solved).
- First success / episodes reaching goal: from each run's `reached_goal` column, as the
  training app recorded it (`torchrl_mbe.episodes.reached_goal`: the flag on MountainCar and
  Acrobot, a landing at rest on LunarLander, balancing to the time limit on CartPole).
- Max position: the largest position among the saved visited states.
- Learning curves: mean over seeds with min-max band, cut to the shortest seed.
- Coverage figure: the seed with the best coverage of each method ("best of N runs").
"""


def _env_section(
    env: str, runs: Sequence[Run], out_dir: Path, colors: dict[str, str], window: int, bins: int
) -> tuple[list[str], list[Path]]:
    """The markdown lines and figures of one environment."""
    lines, written = [f"## {env}", ""], []
    learning = _group([r for r in runs if not r.is_exploration])
    if learning:
        lines += _learning_section(learning, window)
        figure = _plot_learning_curves(env, learning, colors, window, out_dir / f"learning_curves_{_file_stem(env)}.png")
        if figure is not None:
            written.append(figure)
            lines += [f"![learning curves]({figure.name})", ""]
    exploration = _group([r for r in runs if r.is_exploration])
    if exploration:
        bounds, fitted = _env_bounds(env, runs)
        lines += _exploration_section(exploration, bounds, fitted, window, bins)
        best = _best_runs(exploration, bounds, bins) if bounds is not None else {}
        if best:
            written.append(_plot_coverage(env, best, bounds, bins, out_dir / f"coverage_{_file_stem(env)}.png"))
            shown = ", ".join(f"{method} seed {run.seed} ({coverage:.1%})" for method, (run, coverage, _) in best.items())
            lines += [f"![visited states]({written[-1].name})", "", f"Panels, best-covering seed per method: {shown}.", ""]
    return lines, written


def _best_runs(groups: dict[str, list[Run]], bounds: EnvBounds, bins: int) -> dict[str, tuple[Run, float, int]]:
    """Per method with visited states: its best-covering run, that coverage, and how many runs competed."""
    best = {}
    for method, runs in groups.items():
        scored = [(_plane_coverage(r, bounds, bins), r) for r in runs if r.visited_states is not None]
        if scored:
            coverage, run = max(scored, key=lambda pair: pair[0])
            best[method] = (run, coverage, len(scored))
    return best


def write_report(runs: Sequence[Run], out_dir: str | Path, *, window: int = 100, bins: int = 20) -> list[Path]:
    """Writes the figures and ``results.md`` of ``runs`` into ``out_dir``; returns the written paths.

    Keyword Args:
        window (int): running-average window in episodes. Defaults to 100.
        bins (int): coverage grid cells per dimension. Defaults to 20.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    learning_methods = sorted({r.method for r in runs if not r.is_exploration}, key=_method_key)
    colors = {m: f"C{i % 10}" for i, m in enumerate(learning_methods)}
    envs = sorted({r.env for r in runs})
    lines = ["# Results", "", f"{len(runs)} runs in {len(envs)} environment(s).", ""]
    written: list[Path] = []
    for env in envs:
        env_lines, env_figures = _env_section(env, [r for r in runs if r.env == env], out_dir, colors, window, bins)
        lines += env_lines
        written += env_figures
    lines.append(_DEFINITIONS.format(w=window))
    results = out_dir / "results.md"
    results.write_text("\n".join(lines) + "\n")
    written.append(results)
    for path in written:
        logger.info("Wrote %s", path)
    return written


# ----------------------------------------------------------------------------- CLI


def _positive_int(text: str) -> int:
    if not text.isdigit() or int(text) < 1:
        raise argparse.ArgumentTypeError(f"{text!r} is not a positive integer")
    return int(text)


def main(argv: Sequence[str] | None = None) -> None:
    """The ``torchrl-mbe-report`` command: reads ``RUNS_DIR``, writes the report, prints its paths."""
    parser = argparse.ArgumentParser(prog="torchrl-mbe-report", description=__doc__.splitlines()[0])
    parser.add_argument("runs_dir", type=Path, metavar="RUNS_DIR", help="holds the run directories, at any depth")
    parser.add_argument("--out", type=Path, default=None, help="output directory (default: RUNS_DIR/report)")
    parser.add_argument("--window", type=_positive_int, default=100, help="running-average window (default: 100 episodes)")
    parser.add_argument("--bins", type=_positive_int, default=20, help="coverage grid cells per dimension (default: 20)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        runs = load_runs(args.runs_dir)
        written = write_report(runs, args.out or args.runs_dir / "report", window=args.window, bins=args.bins)
    except (RunFormatError, OSError) as err:
        raise SystemExit(f"torchrl-mbe-report: error: {err}") from None
    for path in written:
        print(path)


if __name__ == "__main__":
    main()
