"""The report's tables and ``results.md``: :func:`write_report`."""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from torchrl_mbe.envs.registry import EnvBounds
from torchrl_mbe.report.across import across_tasks_rows
from torchrl_mbe.report.figures import (
    plot_coverage,
    plot_deepsea_scaling,
    plot_frames_to_solved,
    plot_greedy_evaluations,
    plot_learning_curves,
    plot_performance_profiles,
)
from torchrl_mbe.report.metrics import max_position, pairwise_coverage
from torchrl_mbe.report.runs import (
    DEEPSEA,
    Growth,
    Run,
    deepsea_growth,
    deepsea_scaling,
    env_bounds,
    file_stem,
    group_runs,
    plane_coverage,
    solved_count,
    solved_threshold,
)

__all__ = ["write_report"]

logger = logging.getLogger(__name__)

_MISSING = "–"


def _fmt(value: float | None, digits: int = 1) -> str:
    if value is None:
        return _MISSING
    return str(value) if isinstance(value, int) else f"{value:.{digits}f}"


def _reduce(reduce: Callable[[list[float]], float], values: Sequence[float | None], digits: int = 1) -> str:
    """``reduce`` (np.mean, np.median) of the values that are not ``None``, formatted; ``–`` for none."""
    present = [v for v in values if v is not None]
    return _fmt(float(reduce(present)), digits) if present else _MISSING


def _mean_and_seeds(values: Sequence[float | None], digits: int = 1) -> str:
    """``mean [per seed]``; the mean is over the seeds that have a value."""
    return f"{_reduce(np.mean, values, digits)} [{', '.join(_fmt(v, digits) for v in values)}]"


def _percent_and_seeds(fractions: Sequence[float]) -> str:
    """``mean ± std [per seed]`` of fractions, in percent; ``–`` for none."""
    if not fractions:
        return _MISSING
    percent = 100.0 * np.asarray(fractions)
    per_seed = ", ".join(f"{v:.1f}%" for v in percent)
    return f"{percent.mean():.1f}% ± {percent.std():.1f}% [{per_seed}]"


def _count_median_range(values: Sequence[int | None]) -> str:
    """``found/runs, median [min, max]`` of the values that are not ``None``; ``0/runs`` if none is.

    Examples:
        >>> _count_median_range([120, None, 80, 400])
        '3/4, 120 [80, 400]'
        >>> _count_median_range([None, None])
        '0/2'
    """
    present = [v for v in values if v is not None]
    if not present:
        return f"0/{len(values)}"
    return f"{len(present)}/{len(values)}, {_fmt(float(np.median(present)), 0)} [{min(present)}, {max(present)}]"


def _table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return lines + ["| " + " | ".join(row) + " |" for row in rows]


def _summary_section(groups: dict[str, list[Run]], bounds: EnvBounds | None, bins: int, window: int) -> list[str]:
    """One row per method: how often and how fast it solved, and what its exploration cost and covered.

    Coverage is over the first visited states of each run, as many as the shortest run of the table
    visited, so that runs that stopped early and runs that went on are compared on equal frames.
    """
    visited = [r.visited_states for runs in groups.values() for r in runs if r.visited_states is not None]
    frames = min((len(states) for states in visited), default=None)
    coverage_header = "coverage (mean)" if frames is None else f"coverage of the first {frames} frames (mean)"
    rows = []
    for method, runs in groups.items():
        summaries = [r.summary for r in runs]
        with_states = [r for r in runs if r.visited_states is not None] if bounds is not None else []
        coverage = [100.0 * plane_coverage(r, bounds, bins, first=frames) for r in with_states]
        rows.append(
            [
                method,
                solved_count(runs),
                _reduce(np.median, [s.get("solved_at_frames") for s in summaries], 0),
                _reduce(np.median, [s.get("solved_at_wall_time_s") for s in summaries], 0),
                _reduce(np.median, [r.stats(window).first_success_episode for r in runs], 0),
                _reduce(np.mean, [r.final_eval_return for r in runs]),
                _reduce(np.mean, coverage) + "%" * bool(coverage),
                _reduce(np.mean, [s.get("frames_per_s") for s in summaries], 0),
            ]
        )
    header = [
        "method",
        "solved",
        "frames to solved (median)",
        "seconds to solved (median)",
        "first success episode (median)",
        "final greedy eval (mean)",
        coverage_header,
        "frames/s (mean)",
    ]
    note = (
        "Medians of frames and seconds to solved are over the seeds that solved; the per-seed values are in the "
        "tables below."
    )
    return ["### Summary", "", *_table(header, rows), "", note, ""]


def _learning_section(groups: dict[str, list[Run]], window: int) -> list[str]:
    threshold = solved_threshold(groups)
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
        "method",
        "seeds",
        "episodes",
        "first success episode",
        "successful episodes",
        f"best {window}-ep avg",
        f"final {window}-ep avg",
        "final greedy eval",
        "solved (episode)",
    ]
    return [f"### Learning ({solved_at})", "", *_table(header, rows), ""]


def _greedy_section(groups: dict[str, list[Run]]) -> list[str]:
    """Greedy evaluations from the runs' summaries: solved or not at the end, best, and how fast."""
    threshold = solved_threshold(groups)
    rows = []
    for method, runs in groups.items():
        summaries = [r.summary for r in runs]
        rows.append(
            [
                method,
                ", ".join(str(r.seed) for r in runs),
                solved_count(runs),
                _mean_and_seeds([r.final_eval_return for r in runs]),
                _mean_and_seeds([s.get("best_eval_return") for s in summaries]),
                _mean_and_seeds([s.get("solved_at_frames") for s in summaries], 0),
                _mean_and_seeds([s.get("solved_at_wall_time_s") for s in summaries], 0),
                _mean_and_seeds([s.get("wall_time_s") for s in summaries], 0),
                _mean_and_seeds([s.get("frames_per_s") for s in summaries], 0),
            ]
        )
    header = [
        "method",
        "seeds",
        "solved (final greedy >= threshold)",
        "final greedy eval",
        "best periodic greedy eval",
        "frames to first solved eval",
        "seconds to first solved eval",
        "run seconds",
        "frames/s",
    ]
    at = "" if threshold is None else f" (threshold {threshold:g})"
    return [f"### Greedy evaluations{at}", "", *_table(header, rows), ""]


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
            row.append(_percent_and_seeds([plane_coverage(r, bounds, bins) for r in with_states]))
            if pair_dims:
                row.append(_percent_and_seeds([pairwise_coverage(r.visited_states, bounds, bins) for r in with_states]))
            if bounds.progress_dim is not None:
                row.append(
                    _mean_and_seeds([max_position(r.visited_states, bounds.progress_dim) for r in with_states], 3)
                )
        rows.append(row)
    lines = ["### Exploration", "", *_table(header, rows), ""]
    if bounds is not None:
        box = ", ".join(
            f"{bounds.labels[d]} in [{bounds.low[d]:.3g}, {bounds.high[d]:.3g}]" for d in bounds.coverage_dims
        )
        source = (
            "fitted to this environment's visited states: it has no entry in the task registry" if fitted else "fixed"
        )
        lines += [
            (
                f"Coverage: fraction of the cells of a {bins}x{bins} grid holding a visited state; box ({source}): {box}. "
                "Coverage and max values are over the seeds that saved visited states."
            ),
            "",
        ]
    return lines


_DEFINITIONS = """\
## How to read these tables

- `mean [per seed]`: the mean is over the seeds that have a value; `–` means none
  (never reached the goal, never solved, no evaluation).
- Greedy evaluations: from each run's `summary.json`. *Final* is the 100-episode greedy
  evaluation at the end of the run, *best periodic* the best of the evaluations during it,
  *first solved eval* the first periodic evaluation at or above the threshold (where
  `train.stop_when_solved` ends the run); `–` means never.
- Running average at episode i: mean return of episodes max(1, i-{w}+1) .. i, so curves
  start at episode 1. *Best* average only counts windows of {w} episodes (all of them
  if the run is shorter); *final* is the last {w} episodes.
- Solved: first episode at which the mean of the last full {w} episodes reached the
  threshold (gymnasium's definition; a run shorter than {w} episodes is never solved).
- First success / episodes reaching goal: from each run's `reached_goal` column, as the
  training app recorded it (`torchrl_mbe.envs.reached_goal`: the flag on MountainCar and
  Acrobot, a landing at rest on LunarLander, balancing to the time limit on CartPole).
- Max position: the largest position among the saved visited states.
- Learning curves: mean over seeds with min-max band; past a shorter run's end, over the runs still going.
- Groups: one per method and config (tag and config fingerprint); a method run with several configs
  is labelled `method [tag config]`.
- Coverage figure: the seed with the best coverage of each method ("best of N runs").
"""


def _env_section(env: str, runs: Sequence[Run], out_dir: Path, window: int, bins: int) -> tuple[list[str], list[Path]]:
    """The markdown lines and figures of one environment."""
    lines, written = [f"## {env}", ""], []
    bounds, fitted = env_bounds(env, runs)
    learning = group_runs([r for r in runs if not r.is_exploration])
    if learning:
        colors = {label: f"C{i % 10}" for i, label in enumerate(learning)}  # one per group of this env
        stem = file_stem(env)
        lines += _summary_section(learning, bounds, bins, window)
        figure = plot_frames_to_solved(env, learning, colors, out_dir / f"frames_to_solved_{stem}.png")
        lines += _embed(figure, "frames to solved", written)
        lines += _greedy_section(learning)
        figure = plot_greedy_evaluations(env, learning, colors, out_dir / f"greedy_evaluations_{stem}.png")
        lines += _embed(figure, "greedy evaluations", written)
        lines += _learning_section(learning, window)
        figure = plot_learning_curves(env, learning, colors, window, out_dir / f"learning_curves_{stem}.png")
        lines += _embed(figure, "learning curves", written)
    # learning runs too, if saved
    exploration = group_runs([r for r in runs if r.is_exploration or r.visited_states is not None])
    if exploration:
        lines += _exploration_section(exploration, bounds, fitted, window, bins)
        best = _best_runs(exploration, bounds, bins) if bounds is not None else {}
        if best:
            written.append(plot_coverage(env, best, bounds, bins, out_dir / f"coverage_{file_stem(env)}.png"))
            shown = ", ".join(
                f"{method} seed {run.seed} ({coverage:.1%})" for method, (run, coverage, _) in best.items()
            )
            lines += [
                f"![visited states]({written[-1].name})",
                "",
                f"Panels, best-covering seed per method: {shown}.",
                "",
            ]
    return lines, written


def _deepsea_scaling_section(
    scaling: dict[str, dict[int, list[Run]]], out_dir: Path, window: int
) -> tuple[list[str], list[Path]]:
    """The scaling figure and tables of DeepSea at several sizes: one row per method, one column per N."""
    sizes = sorted({size for by_size in scaling.values() for size in by_size})
    header = ["method", *(f"N = {size}" for size in sizes)]

    def rows(episode_of: Callable[[Run], int | None]) -> list[list[str]]:
        return [
            [method, *(_count_median_range(by_size[n]) if n in by_size else _MISSING for n in sizes)]
            for method, by_size in _episodes(scaling, episode_of).items()
        ]

    written: list[Path] = []
    most_episodes = max(len(run.returns) for by_size in scaling.values() for runs in by_size.values() for run in runs)
    figure = plot_deepsea_scaling(
        _episodes(scaling, lambda run: run.episodes_to_solved), most_episodes, out_dir / f"scaling_{DEEPSEA}.png"
    )
    lines = [f"## {DEEPSEA}: scaling with size N", "", *_embed(figure, "episodes to solved against N", written)]
    lines += ["### Episodes to solved", "", *_table(header, rows(lambda run: run.episodes_to_solved)), ""]
    growth_header = ["method", "episodes to solved ~ N^k: k", "sizes fitted", "first treasure ~ N^k: k", "sizes fitted"]
    lines += ["### Growth with N", "", *_table(growth_header, _growth_rows(scaling, window)), ""]
    lines += [
        "### Episodes to the first treasure",
        "",
        *_table(header, rows(lambda run: run.stats(window).first_success_episode)),
        "",
    ]
    lines += [
        (
            "Cells: seeds that got there / seeds run, then the median [min, max] over the seeds that did; `–`: not run. "
            "Episodes to solved: training episodes finished by the first periodic greedy evaluation at or above the "
            "threshold (`solved_at_frames`; unsolved: never one). First treasure: the first training episode that reached "
            "it. Growth: the least-squares slope of log(median episodes) on log N over the sizes where at least half "
            "of the seeds got there, a straight line on the figure's log-log axes. Dithering needs about 2^N episodes to find the "
            "treasure once (bsuite, Osband et al. 2020), the dashed line."
        ),
        "",
    ]
    return lines, written


def _growth_rows(scaling: dict[str, dict[int, list[Run]]], window: int) -> list[list[str]]:
    """Per method: the exponents k of episodes to solved and to the first treasure ~ N^k, each with its sizes (``–``: fewer than two)."""

    def cells(growth: Growth | None) -> list[str]:
        return [_MISSING, _MISSING] if growth is None else [f"{growth.exponent:.2f}", ", ".join(map(str, growth.sizes))]

    def first_treasure(run: Run) -> int | None:
        return run.stats(window).first_success_episode

    to_solved = _episodes(scaling, lambda run: run.episodes_to_solved)
    to_treasure = _episodes(scaling, first_treasure)
    return [
        [method, *cells(deepsea_growth(to_solved[method])), *cells(deepsea_growth(to_treasure[method]))]
        for method in scaling
    ]


def _episodes(
    scaling: dict[str, dict[int, list[Run]]], episode_of: Callable[[Run], int | None]
) -> dict[str, dict[int, list[int | None]]]:
    """``episode_of`` each run of ``scaling``, by method and size."""
    return {
        method: {size: [episode_of(run) for run in runs] for size, runs in by_size.items()}
        for method, by_size in scaling.items()
    }


def _embed(figure: Path | None, alt: str, written: list[Path]) -> list[str]:
    """The markdown lines showing ``figure`` (none if it was not drawn); records it in ``written``."""
    if figure is None:
        return []
    written.append(figure)
    return [f"![{alt}]({figure.name})", ""]


def _best_runs(groups: dict[str, list[Run]], bounds: EnvBounds, bins: int) -> dict[str, tuple[Run, float, int]]:
    """Per method with visited states: its best-covering run, that coverage, and how many runs competed."""
    best = {}
    for method, runs in groups.items():
        scored = [(plane_coverage(r, bounds, bins), r) for r in runs if r.visited_states is not None]
        if scored:
            coverage, run = max(scored, key=lambda pair: pair[0])
            best[method] = (run, coverage, len(scored))
    return best


def _across_tasks_section(runs: Sequence[Run], out_dir: Path) -> tuple[list[str], list[Path]]:
    """The methods compared across tasks (:mod:`torchrl_mbe.report.across`): a table and the performance profiles."""
    rows, scores = across_tasks_rows(runs)
    if not rows:
        return [], []
    figure = plot_performance_profiles(scores, out_dir / "across_tasks_profiles.png")
    header = ["method", "tasks", "runs", "normalized score, IQM [95% CI]", "budget to solved, IQM [95% CI]"]
    note = (
        "Interquartile means over every seed of every task, with stratified bootstrap 95% confidence intervals "
        "(2,000 resamples of the seeds within each task). Normalized score: the final greedy return, 0 at the lowest "
        "return of any episode of any run of the task and 1 at its solved threshold (the success rate on success-rate tasks); "
        "budget to solved: frames to the first solved evaluation over the task's longest run (1 if never solved)."
    )
    written: list[Path] = []
    lines = ["## Across tasks", "", note, "", *_table(header, rows), ""]
    return [*lines, *_embed(figure, "performance profiles across tasks", written)], written


def write_report(runs: Sequence[Run], out_dir: str | Path, *, window: int = 100, bins: int = 20) -> list[Path]:
    """Writes the figures and ``results.md`` of ``runs`` into ``out_dir``; returns the written paths.

    Keyword Args:
        window (int): running-average window in episodes. Defaults to 100.
        bins (int): coverage grid cells per dimension. Defaults to 20.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    envs = sorted({r.env for r in runs})
    lines = ["# Results", "", f"{len(runs)} runs in {len(envs)} environment(s).", ""]
    written: list[Path] = []
    for env in envs:
        env_lines, env_figures = _env_section(env, [r for r in runs if r.env == env], out_dir, window, bins)
        lines += env_lines
        written += env_figures
    across_lines, across_figures = _across_tasks_section(runs, out_dir)
    lines += across_lines
    written += across_figures
    scaling = deepsea_scaling(runs)
    if scaling:
        scaling_lines, scaling_figures = _deepsea_scaling_section(scaling, out_dir, window)
        lines += scaling_lines
        written += scaling_figures
    lines.append(_DEFINITIONS.format(w=window))
    results = out_dir / "results.md"
    results.write_text("\n".join(lines) + "\n")
    written.append(results)
    for path in written:
        logger.info("Wrote %s", path)
    return written
