"""The report's figures: learning curves (the paper's Figures 2 and 4), visited states (Figures 1 and 3) and DeepSea's scaling."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter, MaxNLocator

from torchrl_mbe.envs.registry import EnvBounds
from torchrl_mbe.report.intervals import performance_profile
from torchrl_mbe.report.metrics import running_average
from torchrl_mbe.report.runs import DEEPSEA, Run, deepsea_growth, solved_count, solved_threshold

__all__ = [
    "last_finished_episode",
    "mean_curve",
    "plot_coverage",
    "plot_deepsea_scaling",
    "plot_explorers_by_task",
    "plot_frames_to_solved",
    "plot_greedy_evaluations",
    "plot_learning_curves",
    "save_figure",
]

logger = logging.getLogger(__name__)


def save_figure(fig: Figure, path: Path) -> Path:
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=120)
    return path


def plot_learning_curves(
    env: str, groups: dict[str, list[Run]], colors: dict[str, str], window: int, path: Path
) -> Path | None:
    """Running average return per episode, mean over seeds with a min-max band; ``None`` if no run has episodes.

    Runs of unequal length are not cut: past a run's last episode, the mean and
    band are over the runs still going, and the label says so.
    """
    fig = Figure(figsize=(8, 5), layout="constrained")
    ax = fig.add_subplot()
    plotted = False
    for method, runs in groups.items():
        curves = [running_average(r.returns, window) for r in runs if len(r.returns)]
        if not curves:
            continue
        mean, low, high = mean_curve(curves)
        episodes = np.arange(1, len(mean) + 1)
        seeds = len({run.seed for run in runs})
        shortest = min(len(c) for c in curves)
        label = f"{method} ({seeds} seed{'s' * (seeds > 1)}"
        label += ")" if shortest == len(mean) else f"; after episode {shortest}: the runs still going)"
        ax.plot(episodes, mean, color=colors[method], label=label)
        ax.fill_between(episodes, low, high, color=colors[method], alpha=0.2, linewidth=0)
        plotted = True
    if not plotted:
        return None
    labels = ("training episode", f"return, running average of last {window} episodes")
    return _finish_returns_plot(
        fig, groups, labels, f"{env}: learning curves (line: mean over seeds, band: min to max)", path
    )


def plot_greedy_evaluations(env: str, groups: dict[str, list[Run]], colors: dict[str, str], path: Path) -> Path | None:
    """Every run's greedy evaluations against frames, one colour per method; ``None`` if no run evaluated.

    One line per seed (runs that stop when solved end early); the last point of a
    line is its final 100-episode evaluation.
    """
    fig = Figure(figsize=(8, 5), layout="constrained")
    ax = fig.add_subplot()
    plotted = False
    for method, runs in groups.items():
        evaluated = [run for run in runs if len(run.eval_returns)]
        for index, run in enumerate(evaluated):
            label = f"{method} ({len({r.seed for r in evaluated})} seeds)" if index == 0 else None
            ax.plot(run.eval_frames, run.eval_returns, color=colors[method], alpha=0.7, marker=".", label=label)
            plotted = True
    if not plotted:
        return None
    labels = ("frames", "greedy return (mean over the evaluation's episodes)")
    return _finish_returns_plot(fig, groups, labels, f"{env}: greedy evaluations, one line per seed", path)


def plot_frames_to_solved(env: str, groups: dict[str, list[Run]], colors: dict[str, str], path: Path) -> Path | None:
    """Per method, each seed's frames to its first solved evaluation (dots) or its whole run if it never solved
    (crosses); ``None`` if no run has a ``solved`` flag in its summary."""
    fig = Figure(figsize=(max(6.0, 1.1 * len(groups) + 2.0), 4.5), layout="constrained")
    ax = fig.add_subplot()
    plotted = False
    for column, (method, runs) in enumerate(groups.items()):
        judged = [run.summary for run in runs if "solved" in run.summary]
        solved = [s["solved_at_frames"] for s in judged if s["solved"] and s.get("solved_at_frames") is not None]
        unsolved = [s["frames"] for s in judged if not s["solved"]]
        offsets = np.linspace(-0.15, 0.15, max(len(judged), 1))
        ax.scatter(column + offsets[: len(solved)], solved, color=colors[method], marker="o", zorder=3)
        ax.scatter(column + offsets[len(solved) : len(judged)], unsolved, color=colors[method], marker="x", zorder=3)
        if solved:
            ax.hlines(np.median(solved), column - 0.3, column + 0.3, color=colors[method], linewidth=2)
        plotted = plotted or bool(judged)
    if not plotted:
        return None
    ax.set_xticks(range(len(groups)), [f"{m}\n{solved_count(r)} solved" for m, r in groups.items()], fontsize=8)
    ax.set_ylabel("frames")
    ax.set_ylim(bottom=0)
    ax.set_title(f"{env}: frames to solved\n(dots, bar: median) or run length if never solved (crosses)", fontsize=10)
    ax.grid(alpha=0.3, axis="y")
    return save_figure(fig, path)


def plot_deepsea_scaling(scaling: dict[str, dict[int, list[int | None]]], most_episodes: int, path: Path) -> Path:
    """Episodes to solved against DeepSea's size N, log-log, beside dithering's 2^N.

    ``scaling[method][N]`` holds each seed's episodes to solved at size N (``None``: never
    solved); ``most_episodes`` is the longest run's episodes. One dot per seed that solved
    and a line through each method's medians over them, its growth exponent
    (:func:`~torchrl_mbe.report.runs.deepsea_growth`) in the legend; one cross per seed
    that did not, stacked down from the top edge, above ``most_episodes``. Methods are
    shifted a little sideways so that their markers do not hide each other.
    """
    fig = Figure(figsize=(8, 5.5), layout="constrained")
    ax = fig.add_subplot()
    top_edge = ax.get_xaxis_transform()  # x in data, y in axes coordinates
    sizes = sorted({size for by_size in scaling.values() for size in by_size})
    for index, (method, by_size) in enumerate(scaling.items()):
        color, shift = f"C{index % 10}", 1.0 + 0.025 * (index - (len(scaling) - 1) / 2)
        medians = []
        for size, episodes in by_size.items():
            solved = [count for count in episodes if count is not None]
            ax.scatter([size * shift] * len(solved), solved, color=color, alpha=0.5, s=18, zorder=3)
            if solved:
                medians.append((size * shift, float(np.median(solved))))
            unsolved = len(episodes) - len(solved)
            heights = 0.97 - 0.03 * np.arange(unsolved)
            ax.scatter([size * shift] * unsolved, heights, transform=top_edge, color=color, marker="x", s=30, zorder=4)
        xs, ys = zip(*medians) if medians else ((), ())
        growth = deepsea_growth(by_size)
        ax.plot(
            xs, ys, color=color, marker="o", label=method if growth is None else f"{method}: ~N^{growth.exponent:.1f}"
        )
    dense = np.geomspace(sizes[0], sizes[-1], 100)  # 2^N bends on log-log axes
    ax.plot(dense, 2.0**dense, color="0.3", linestyle="--", linewidth=1, label="dithering: 2^N")
    ax.scatter([], [], color="0.3", marker="x", label="unsolved: one cross per seed, at the top")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_ylim(1, 10.0 * max(most_episodes, 2.0 ** sizes[0]))  # the crosses stay above every run's episodes
    ax.set_xticks(sizes, [str(size) for size in sizes])
    ax.set_xticks([], minor=True)
    ax.set_xlabel(f"{DEEPSEA} size N")
    ax.set_ylabel("episodes to solved")
    ax.set_title(f"{DEEPSEA}: episodes to solved (dots: seeds, line: median of the seeds that solved)", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    return save_figure(fig, path)


def plot_explorers_by_task(
    frames: dict[str, dict[str, list[int | None]]], explorers: list[str], budgets: dict[str, int], path: Path
) -> Path:
    """Each explorer's frames to solved on each task, one panel a task: a dot per seed that solved, a bar at their median.

    ``frames[task][explorer]`` holds each seed's frames to its first solved evaluation
    (``None``: never solved); ``explorers`` are the rows, top to bottom, and an explorer
    without runs on a task is left out of its panel.
    A seed that never solved is a cross at the task's budget (``budgets[task]``, its longest
    run), so what failed is as visible as what solved.
    """
    tasks = list(frames)
    fig = Figure(figsize=(3.2 * len(tasks), 0.45 * len(explorers) + 1.6), layout="constrained")
    axes = fig.subplots(1, len(tasks), sharey=True, squeeze=False)[0]
    for ax, task in zip(axes, tasks):
        for row, explorer in enumerate(explorers):
            seeds = frames[task].get(explorer)
            if seeds is None:
                ax.text(budgets[task] / 2, row, "not run", color="0.6", ha="center", va="center", fontsize=8)
                continue
            solved = [count for count in seeds if count is not None]
            jitter = np.linspace(-0.15, 0.15, len(seeds))
            ax.scatter(solved, row + jitter[: len(solved)], color=f"C{row % 10}", s=16, alpha=0.7, zorder=3)
            unsolved = len(seeds) - len(solved)
            ax.scatter([budgets[task]] * unsolved, row + jitter[len(solved) :], color="0.3", marker="x", s=20, zorder=3)
            if solved:
                ax.plot([np.median(solved)] * 2, [row - 0.3, row + 0.3], color=f"C{row % 10}", linewidth=2)
        ax.set_xlim(0, budgets[task] * 1.05)
        ax.xaxis.set_major_formatter(FuncFormatter(lambda value, _: f"{value / 1000:.0f}k"))
        ax.set_title(task, fontsize=9)
        ax.set_xlabel("frames to solved")
        ax.grid(alpha=0.3, axis="x")
    axes[0].set_yticks(range(len(explorers)), explorers)
    axes[0].invert_yaxis()
    fig.suptitle("Frames to the first solved evaluation (dots: seeds, bar: median; x: never solved)", fontsize=10)
    return save_figure(fig, path)


def _finish_returns_plot(
    fig: Figure, groups: dict[str, list[Run]], axis_labels: tuple[str, str], title: str, path: Path
) -> Path:
    """The solved threshold as a dashed line, axis labels, title, grid and legend; saves the figure."""
    ax = fig.axes[0]
    threshold = solved_threshold(groups)
    if threshold is not None:
        ax.axhline(threshold, color="0.3", linestyle="--", linewidth=1, label=f"solved ({threshold:g})")
    ax.set_xlabel(axis_labels[0])
    ax.set_ylabel(axis_labels[1])
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(loc="best")
    return save_figure(fig, path)


def mean_curve(curves: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean, min and max over ``curves`` at each index, over the curves that reach it.

    Examples:
        >>> import numpy as np
        >>> from torchrl_mbe.report.figures import mean_curve
        >>> mean, low, high = mean_curve([np.array([1.0, 2.0]), np.array([3.0])])
        >>> mean.tolist(), high.tolist()
        ([2.0, 2.0], [3.0, 2.0])
    """
    stacked = np.full((len(curves), max(len(c) for c in curves)), np.nan)
    for row, curve in zip(stacked, curves):
        row[: len(curve)] = curve
    return np.nanmean(stacked, 0), np.nanmin(stacked, 0), np.nanmax(stacked, 0)


def last_finished_episode(runs: list[Run]) -> int:
    """The colour bar's top: the most episodes a run finished (states of an unfinished last episode share its colour)."""
    return max(max(len(run.returns), 1) for run in runs)


_COVERAGE_COLUMNS = 4  # panels per row of the coverage figure


def plot_coverage(env: str, best: dict[str, tuple[Run, float, int]], bounds: EnvBounds, bins: int, path: Path) -> Path:
    """One scatter panel per method, of its best-covering run: ``best[method] = (run, coverage, num_seeds)``."""
    x_dim, y_dim = bounds.plane
    columns = min(len(best), _COVERAGE_COLUMNS)
    rows = -(-len(best) // columns)
    fig = Figure(figsize=(4.2 * columns + 1.0, 4.0 * rows + 0.4), layout="constrained")
    grid = fig.subplots(rows, columns, squeeze=False, sharex=True, sharey=True)
    for ax in grid.flat[len(best) :]:
        ax.set_visible(False)
    axes = grid.flat[: len(best)]
    norm = Normalize(1, last_finished_episode([run for run, _, _ in best.values()]))
    scatter = None
    for ax, (method, (run, coverage, num_seeds)) in zip(axes, best.items()):
        states = run.visited_states
        scatter = ax.scatter(
            states[:, x_dim],
            states[:, y_dim],
            c=run.visited_episodes,
            cmap="viridis",
            norm=norm,
            s=2,
            linewidths=0,
            rasterized=True,
        )
        ax.set_title(f"{method}\ncoverage {coverage:.1%} (seed {run.seed}, best of {num_seeds})", fontsize=10)
        ax.set_xlabel(bounds.labels[x_dim])
        ax.grid(alpha=0.3)
    for ax in grid[:, 0]:
        ax.set_ylabel(bounds.labels[y_dim])
    all_states = np.concatenate([run.visited_states for run, _, _ in best.values()])
    for set_lim, dim in ((axes[0].set_xlim, x_dim), (axes[0].set_ylim, y_dim)):
        set_lim(min(bounds.low[dim], all_states[:, dim].min()), max(bounds.high[dim], all_states[:, dim].max()))
    fig.colorbar(scatter, ax=list(axes), label="episode", ticks=MaxNLocator(integer=True))
    fig.suptitle(f"{env}: visited states ({bins}x{bins} grid coverage)")
    return save_figure(fig, path)


def plot_performance_profiles(scores: dict[str, dict[str, np.ndarray]], path: Path) -> Path:
    """Each method's fraction of runs (each task weighing the same) whose normalized score exceeds each threshold."""
    thresholds = np.linspace(0.0, 1.5, 61)
    fig = Figure(figsize=(6.5, 4.5), layout="constrained")
    ax = fig.add_subplot()
    for method, per_task in scores.items():
        ax.plot(thresholds, performance_profile(per_task, thresholds), label=method)
    ax.axvline(1.0, color="grey", linestyle=":", linewidth=1)
    ax.set_xlabel("normalized score threshold (1: the solved threshold)")
    ax.set_ylabel("fraction of runs above it")
    ax.set_title("Performance profiles across tasks", fontsize=10)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return save_figure(fig, path)
