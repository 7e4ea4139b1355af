"""The ledger: the recorded runs behind the README's results table and docs/results.md's seed tables, and the tables rendered from them.

``docs/runs/`` holds the ``summary.json`` of every run the table cites (each with its
``record``: commit, machine, versions, command) and ``ledger.json``, one entry per row: the
task, its kind of reward, the folder of its runs and the command that trains it. An entry
with ``"in_readme": false`` (runs at earlier settings, kept for comparison) is a row of the
seed table only. The numbers
come from the summaries only: a run of ``exploration=egreedy`` counts as e-greedy, one of
``exploration=bootstrap`` as Bootstrapped DQN, any other as the default explorer. ``python -m torchrl_mbe.report.ledger docs/runs`` prints the README's
table, ``... --seeds`` the seed by seed table at the top of docs/results.md and ``... --deepsea``
its DeepSea table (``deepsea.json``'s rows, by size); a test fails when a doc's copy differs.
``... --deepsea-figure PNG`` draws the DeepSea scaling figure from the same runs, and
``... --explorers-figure PNG`` the explorer summary's runs.

``explorers.json`` names the explorer by task summary at the top of docs/results.md: its
rows (each explorer's method and label) and columns (each task and the folders of its
runs); ``... --explorers`` prints that table and ``... --across`` the explorers compared
across the tasks every one of them ran, the interquartile mean of their budget to solved
with its stratified bootstrap 95% interval (:mod:`torchrl_mbe.report.across`).
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
from collections.abc import Sequence
from pathlib import Path

from torchrl_mbe.report.across import budget_fractions, iqm_interval
from torchrl_mbe.report.figures import plot_deepsea_scaling, plot_explorers_by_task

__all__ = [
    "DEEPSEA_INDEX",
    "EXPLORERS_INDEX",
    "LEDGER_INDEX",
    "main",
    "render_across_table",
    "render_deepsea_figure",
    "render_deepsea_table",
    "render_explorers_figure",
    "render_explorers_table",
    "render_results_table",
    "render_seeds_table",
]

LEDGER_INDEX = "ledger.json"
DEEPSEA_INDEX = "deepsea.json"  # DeepSea's rows by size: [{"size": N, "runs": folder}, ...]
EXPLORERS_INDEX = "explorers.json"  # {"explorers": {name: label}, "tasks": [{"task": column, "runs": [folder, ...]}]}
EGREEDY = "dqn+egreedy"
BOOTSTRAP = "dqn+bootstrap"
BASELINES = (BOOTSTRAP, EGREEDY)  # in the order the seed table lists them, after the default
HEADER = (
    "| task | reward | default explorer solved | e-greedy solved | Bootstrapped DQN solved "
    "| median frames to solved (default) "
    "| median seconds to solved (default, its seeds at once) | commit | command |"
)
DEEPSEA_HEADER = (
    "| N | explorer | seeds | solved | episodes to solved, each seed | median [min, max] | commit | command |"
)
ACROSS_HEADER = "| explorer | tasks | runs | solved | budget to solved, IQM [95% CI] |"
SEEDS_HEADER = (
    "| task | explorer | solved | frames to the first solved evaluation: median [each seed; unsolved: its final "
    "greedy success rate] | seconds to solved, median (its seeds at once) | commit | command |"
)


def render_results_table(ledger_dir: str | Path) -> str:
    """The README's results table, one row per ``ledger.json`` entry not marked ``"in_readme": false``, from the summaries under ``ledger_dir``.

    Examples:
        >>> import json, tempfile
        >>> from pathlib import Path
        >>> from torchrl_mbe.report.ledger import render_results_table
        >>> ledger = Path(tempfile.mkdtemp())
        >>> for seed, solved_at in enumerate([1000, 3000, None]):
        ...     run = ledger / "toy" / f"seed{seed}"
        ...     run.mkdir(parents=True)
        ...     summary = {"method": "dqn+gaussian", "seed": seed, "solved": solved_at is not None,
        ...                "solved_at_frames": solved_at, "solved_at_wall_time_s": solved_at and solved_at / 100,
        ...                "record": {"commit": "0123456789abcdef"}}
        ...     _ = (run / "summary.json").write_text(json.dumps(summary))
        >>> entry = {"task": "Toy-v0", "reward": "sparse", "runs": "toy", "command": "python train.py env=toy"}
        >>> _ = (ledger / "ledger.json").write_text(json.dumps([entry]))
        >>> print(render_results_table(ledger).splitlines()[-1])
        | Toy-v0 | sparse | 2/3 | not run | not run | 2,000 | 20 | 0123456 | `python train.py env=toy` |
    """
    ledger_dir = Path(ledger_dir)
    entries = json.loads((ledger_dir / LEDGER_INDEX).read_text())
    rows = [_row(entry, _summaries(ledger_dir / entry["runs"])) for entry in entries if entry.get("in_readme", True)]
    return _table(HEADER, rows)


def render_seeds_table(ledger_dir: str | Path) -> str:
    """docs/results.md's seed by seed table: a row per ``ledger.json`` entry and explorer, each seed's frames to solved.

    An unsolved seed shows its final greedy success rate (or return) in parentheses; the
    command is the one its runs recorded.

    Examples:
        >>> import json, tempfile
        >>> from pathlib import Path
        >>> from torchrl_mbe.report.ledger import render_seeds_table
        >>> ledger = Path(tempfile.mkdtemp())
        >>> for seed, solved_at in enumerate([1000, 3000, None]):
        ...     run = ledger / "toy" / f"seed{seed}"
        ...     run.mkdir(parents=True)
        ...     summary = {"method": "dqn+gaussian", "seed": seed, "solved": solved_at is not None,
        ...                "solved_at_frames": solved_at, "solved_at_wall_time_s": solved_at and solved_at / 100,
        ...                "final_eval_success_rate": 0.25, "record": {"commit": "0123456789abcdef",
        ...                "command": "python train.py env=toy population=3"}}
        ...     _ = (run / "summary.json").write_text(json.dumps(summary))
        >>> entry = {"task": "Toy-v0", "reward": "sparse", "runs": "toy", "command": "python train.py env=toy"}
        >>> _ = (ledger / "ledger.json").write_text(json.dumps([entry]))
        >>> print(render_seeds_table(ledger).splitlines()[-1])
        | Toy-v0 | gaussian | 2/3 | 2,000 [1,000, 3,000, (0.25)] | 20 | 0123456 | `python train.py env=toy population=3` |
    """
    ledger_dir = Path(ledger_dir)
    rows = []
    for entry in json.loads((ledger_dir / LEDGER_INDEX).read_text()):
        rows += [_seeds_row(entry["task"], runs) for runs in _by_method(_summaries(ledger_dir / entry["runs"]))]
    return _table(SEEDS_HEADER, rows)


def render_explorers_table(ledger_dir: str | Path) -> str:
    """docs/results.md's summary: a row per explorer of ``explorers.json``, a column per task, each cell its seeds solved and median frames to solved.

    Examples:
        >>> import json, tempfile
        >>> from pathlib import Path
        >>> from torchrl_mbe.report.ledger import render_explorers_table
        >>> ledger = Path(tempfile.mkdtemp())
        >>> for method, solved_at in (("gaussian", [12_000, 20_000]), ("egreedy", [None, 60_000])):
        ...     for seed, frames in enumerate(solved_at):
        ...         run = ledger / "toy" / method / f"seed{seed}"
        ...         run.mkdir(parents=True)
        ...         summary = {"method": f"dqn+{method}", "seed": seed, "solved": frames is not None,
        ...                    "solved_at_frames": frames}
        ...         _ = (run / "summary.json").write_text(json.dumps(summary))
        >>> index = {"explorers": {"gaussian": "gaussian (the default)", "egreedy": "egreedy", "knn": "knn"},
        ...          "tasks": [{"task": "Toy-v0 (sparse)", "runs": ["toy"]}]}
        >>> _ = (ledger / "explorers.json").write_text(json.dumps(index))
        >>> print(render_explorers_table(ledger))
        | explorer | Toy-v0 (sparse) |
        | --- | --- |
        | gaussian (the default) | 2/2, 16k |
        | egreedy | 1/2, 60k |
        | knn | not run |
    """
    index = json.loads((Path(ledger_dir) / EXPLORERS_INDEX).read_text())
    columns = [(task["task"], _task_summaries(ledger_dir, task)) for task in index["tasks"]]
    header = "| explorer | " + " | ".join(task for task, _ in columns) + " |"
    rows = [
        "| " + " | ".join([label, *(_explorer_cell(summaries, name) for _, summaries in columns)]) + " |"
        for name, label in index["explorers"].items()
    ]
    return _table(header, rows)


def render_explorers_figure(ledger_dir: str | Path, path: str | Path) -> Path:
    """The summary's runs drawn: each explorer's frames to solved on each task of ``explorers.json``, a dot per seed.

    Examples:
        >>> import json, tempfile
        >>> from pathlib import Path
        >>> from torchrl_mbe.report.ledger import render_explorers_figure
        >>> ledger = Path(tempfile.mkdtemp())
        >>> for seed, solved_at in enumerate([12_000, None]):
        ...     run = ledger / "toy" / f"seed{seed}"
        ...     run.mkdir(parents=True)
        ...     summary = {"method": "dqn+gaussian", "seed": seed, "solved": solved_at is not None,
        ...                "solved_at_frames": solved_at, "frames": solved_at or 50_000}
        ...     _ = (run / "summary.json").write_text(json.dumps(summary))
        >>> index = {"explorers": {"gaussian": "gaussian"}, "tasks": [{"task": "Toy-v0", "runs": ["toy"]}]}
        >>> _ = (ledger / "explorers.json").write_text(json.dumps(index))
        >>> render_explorers_figure(ledger, ledger / "explorers.png").name
        'explorers.png'
    """
    index = json.loads((Path(ledger_dir) / EXPLORERS_INDEX).read_text())
    frames: dict[str, dict[str, list[int | None]]] = {}
    budgets = {}
    for task in index["tasks"]:
        summaries = _task_summaries(ledger_dir, task)
        budgets[task["task"]] = max(s["frames"] for s in summaries)
        frames[task["task"]] = {
            label: [s["solved_at_frames"] if s["solved"] else None for s in runs]
            for name, label in index["explorers"].items()
            if (runs := _explorer_runs(summaries, name))
        }
    return plot_explorers_by_task(frames, list(index["explorers"].values()), budgets, Path(path))


def render_across_table(ledger_dir: str | Path) -> str:
    """docs/results.md's comparison across tasks: per explorer of ``explorers.json``, over the tasks every one of them ran,
    its seeds solved and the interquartile mean of its budget to solved with a stratified bootstrap 95% interval.

    The budget to solved is a run's frames to its first solved evaluation over the task's
    longest run, 1 if never (:func:`~torchrl_mbe.report.across.budget_fractions`).

    Examples:
        >>> import json, tempfile
        >>> from pathlib import Path
        >>> from torchrl_mbe.report.ledger import render_across_table
        >>> ledger = Path(tempfile.mkdtemp())
        >>> for task in ("A", "B"):
        ...     for method, solved_at in (("gaussian", 500), ("egreedy", None)):
        ...         run = ledger / task / method / "seed0"
        ...         run.mkdir(parents=True)
        ...         summary = {"env": task, "method": f"dqn+{method}", "seed": 0, "solved": solved_at is not None,
        ...                    "solved_at_frames": solved_at, "frames": 1000, "solved_threshold": 1.0,
        ...                    "final_eval_return": 0.0}
        ...         _ = (run / "summary.json").write_text(json.dumps(summary))
        >>> index = {"explorers": {"gaussian": "gaussian", "egreedy": "egreedy"},
        ...          "tasks": [{"task": "A", "runs": ["A"]}, {"task": "B", "runs": ["B"]}]}
        >>> _ = (ledger / "explorers.json").write_text(json.dumps(index))
        >>> print(render_across_table(ledger).splitlines()[-1])
        | egreedy | A, B | 2 | 0/2 | 1.00 [1.00, 1.00] |
    """
    index = json.loads((Path(ledger_dir) / EXPLORERS_INDEX).read_text())
    methods = {f"dqn+{name}" for name in index["explorers"]}
    columns = [_task_summaries(ledger_dir, task) for task in index["tasks"]]
    compared = [s for summaries in columns if methods <= {s["method"] for s in summaries} for s in summaries]
    fractions = budget_fractions([s for s in compared if s["method"] in methods])
    rows = []
    for name, label in index["explorers"].items():
        per_task = fractions.get(f"dqn+{name}")
        if per_task is None:  # fewer than two tasks ran every explorer
            continue
        runs = _explorer_runs(compared, name)
        cells = [label, ", ".join(per_task), str(len(runs)), _solved(runs), iqm_interval(per_task)]
        rows.append("| " + " | ".join(cells) + " |")
    return _table(ACROSS_HEADER, rows)


def render_deepsea_table(ledger_dir: str | Path) -> str:
    """docs/results.md's DeepSea table: a row per ``deepsea.json`` entry and explorer, each seed's episodes to solved.

    Episodes to solved are the frames to the first solved evaluation over ``N`` (an
    episode of DeepSea is ``N`` steps); an unsolved seed shows ``-``. The command is the
    runs' without its ``seed=`` (the seeds column says which).

    Examples:
        >>> import json, tempfile
        >>> from pathlib import Path
        >>> from torchrl_mbe.report.ledger import render_deepsea_table
        >>> ledger = Path(tempfile.mkdtemp())
        >>> for seed, solved_at in enumerate([2000, 4000, None]):
        ...     run = ledger / "deepsea-10" / f"seed{seed}"
        ...     run.mkdir(parents=True)
        ...     summary = {"method": "dqn+bootstrap", "seed": seed, "solved": solved_at is not None,
        ...                "solved_at_frames": solved_at, "record": {"commit": "0123456789abcdef",
        ...                "command": f"python train.py env=deepsea env.size=10 exploration=bootstrap seed={seed}"}}
        ...     _ = (run / "summary.json").write_text(json.dumps(summary))
        >>> _ = (ledger / "deepsea.json").write_text(json.dumps([{"size": 10, "runs": "deepsea-10"}]))
        >>> print(render_deepsea_table(ledger).splitlines()[-1])
        | 10 | bootstrap | 0-2 | 2/3 | 200, 400, - | 300 [200, 400] | 0123456 | `python train.py env=deepsea env.size=10 exploration=bootstrap` |
    """
    ledger_dir = Path(ledger_dir)
    rows = []
    for entry in json.loads((ledger_dir / DEEPSEA_INDEX).read_text()):
        rows += [_deepsea_row(entry["size"], runs) for runs in _by_method(_summaries(ledger_dir / entry["runs"]))]
    return _table(DEEPSEA_HEADER, rows)


def render_deepsea_figure(ledger_dir: str | Path, path: str | Path) -> Path:
    """docs/results.md's DeepSea scaling figure, from the runs of its DeepSea table: each explorer's episodes to solved against N.

    Examples:
        >>> import json, tempfile
        >>> from pathlib import Path
        >>> from torchrl_mbe.report.ledger import render_deepsea_figure
        >>> ledger = Path(tempfile.mkdtemp())
        >>> for size in (10, 20):
        ...     for seed in range(2):
        ...         run = ledger / f"deepsea-{size}" / f"seed{seed}"
        ...         run.mkdir(parents=True)
        ...         summary = {"method": "dqn+bootstrap", "seed": seed, "solved": True, "episodes": 20 * size,
        ...                    "solved_at_frames": 10 * size * size}
        ...         _ = (run / "summary.json").write_text(json.dumps(summary))
        >>> index = [{"size": size, "runs": f"deepsea-{size}"} for size in (10, 20)]
        >>> _ = (ledger / "deepsea.json").write_text(json.dumps(index))
        >>> render_deepsea_figure(ledger, ledger / "scaling.png").name
        'scaling.png'
    """
    ledger_dir = Path(ledger_dir)
    scaling: dict[str, dict[int, list[int | None]]] = {}
    most_episodes = 0
    for entry in json.loads((ledger_dir / DEEPSEA_INDEX).read_text()):
        for runs in _by_method(_summaries(ledger_dir / entry["runs"])):
            explorer = runs[0]["method"].removeprefix("dqn+")
            scaling.setdefault(explorer, {})[entry["size"]] = _episodes_to_solved(entry["size"], runs)
            most_episodes = max(most_episodes, *(s["episodes"] for s in runs))
    return plot_deepsea_scaling(scaling, most_episodes, Path(path))


def _episodes_to_solved(size: int, summaries: Sequence[dict]) -> list[int | None]:
    """Each run's episodes to its first solved evaluation (a DeepSea episode is ``size`` steps); ``None`` if unsolved."""
    return [s["solved_at_frames"] // size if s["solved"] else None for s in summaries]


def _deepsea_row(size: int, summaries: Sequence[dict]) -> str:
    episodes = _episodes_to_solved(size, summaries)
    solved = [count for count in episodes if count is not None]
    seeds = [s["seed"] for s in summaries]
    cells = [
        str(size),
        summaries[0]["method"].removeprefix("dqn+"),
        f"{seeds[0]}-{seeds[-1]}" if seeds == list(range(seeds[0], seeds[-1] + 1)) else ", ".join(map(str, seeds)),
        _solved(summaries),
        ", ".join("-" if count is None else f"{count:,}" for count in episodes),
        f"{_median(solved)} [{min(solved):,}, {max(solved):,}]" if solved else "–",
        _commits(summaries),
        _commands({_without_seed(s["record"]["command"]) for s in summaries}),
    ]
    return "| " + " | ".join(cells) + " |"


def _without_seed(command: str) -> str:
    return re.sub(r" seed=\d+", "", command)


def _by_method(summaries: Sequence[dict]) -> list[list[dict]]:
    """The runs of each method, the default's first and then :data:`BASELINES`' order, each method's by seed."""
    methods = sorted({s["method"] for s in summaries}, key=lambda method: (_listed_after_default(method), method))
    return [sorted((s for s in summaries if s["method"] == method), key=_seed) for method in methods]


def _commands(commands: set[str]) -> str:
    return " / ".join(f"`{command}`" for command in sorted(commands))


def _listed_after_default(method: str) -> int:
    return BASELINES.index(method) + 1 if method in BASELINES else 0


def _seed(summary: dict) -> int:
    return summary["seed"]


def _seeds_row(task: str, summaries: Sequence[dict]) -> str:
    solved = [s for s in summaries if s["solved"]]
    each = ", ".join(f"{s['solved_at_frames']:,}" if s["solved"] else f"({_final(s)})" for s in summaries)
    cells = [
        task,
        summaries[0]["method"].removeprefix("dqn+"),
        _solved(summaries),
        f"{_median([s['solved_at_frames'] for s in solved])} [{each}]",
        _median([s["solved_at_wall_time_s"] for s in solved]),
        _commits(summaries),
        _commands({s["record"]["command"] for s in summaries}),
    ]
    return "| " + " | ".join(cells) + " |"


def _final(summary: dict) -> str:
    """An unsolved run's final greedy success rate, or its return where the task has no goal."""
    rate = summary.get("final_eval_success_rate")
    return f"{rate:.2f}" if rate is not None else f"return {summary['final_eval_return']:.2f}"


def _task_summaries(ledger_dir: str | Path, task: dict) -> list[dict]:
    """The summaries of an ``explorers.json`` column: every run under its folders."""
    return [summary for folder in task["runs"] for summary in _summaries(Path(ledger_dir) / folder)]


def _explorer_runs(summaries: Sequence[dict], explorer: str) -> list[dict]:
    """The runs of ``explorer`` (a name of ``explorers.json``) among ``summaries``, by seed."""
    return sorted((s for s in summaries if s["method"] == f"dqn+{explorer}"), key=_seed)


def _explorer_cell(summaries: Sequence[dict], explorer: str) -> str:
    """An explorer's seeds solved out of its runs and, if any solved, the median frames to solved in thousands."""
    runs = _explorer_runs(summaries, explorer)
    solved = [s["solved_at_frames"] for s in runs if s["solved"]]
    return _solved(runs) + (f", {statistics.median(solved) / 1000:,.0f}k" if solved else "")


def _summaries(runs_dir: Path) -> list[dict]:
    return [json.loads(path.read_text()) for path in sorted(runs_dir.rglob("summary.json"))]


def _row(entry: dict, summaries: Sequence[dict]) -> str:
    default = [s for s in summaries if s["method"] not in BASELINES]
    egreedy = [s for s in summaries if s["method"] == EGREEDY]
    bootstrap = [s for s in summaries if s["method"] == BOOTSTRAP]
    solved = [s for s in default if s["solved"]]
    cells = [
        entry["task"],
        entry["reward"],
        _solved(default),
        _solved(egreedy),
        _solved(bootstrap),
        _median([s["solved_at_frames"] for s in solved]),
        _median([s["solved_at_wall_time_s"] for s in solved]),
        _commits(summaries),
        f"`{entry['command']}`",
    ]
    return "| " + " | ".join(cells) + " |"


def _table(header: str, rows: Sequence[str]) -> str:
    return "\n".join([header, "| --- " * header.count(" | ") + "| --- |", *rows])


def _commits(summaries: Sequence[dict]) -> str:
    """The short commits the runs recorded, sorted."""
    return ", ".join(sorted({s["record"]["commit"][:7] for s in summaries}))


def _solved(summaries: Sequence[dict]) -> str:
    if not summaries:
        return "not run"
    return f"{sum(bool(s['solved']) for s in summaries)}/{len(summaries)}"


def _median(values: Sequence[float]) -> str:
    return f"{statistics.median(values):,.0f}" if values else "–"


def main(argv: Sequence[str] | None = None) -> None:
    """Prints a table of the ledger (the README's by default), or draws the DeepSea figure."""
    parser = argparse.ArgumentParser(prog="python -m torchrl_mbe.report.ledger", description=main.__doc__)
    parser.add_argument("ledger_dir", nargs="?", default="docs/runs", help="the ledger (default: docs/runs)")
    which = parser.add_mutually_exclusive_group()
    which.add_argument("--seeds", action="store_true", help="docs/results.md's seed by seed table")
    which.add_argument("--deepsea", action="store_true", help="docs/results.md's DeepSea table")
    which.add_argument("--explorers", action="store_true", help="docs/results.md's explorer by task summary")
    which.add_argument("--across", action="store_true", help="docs/results.md's explorers compared across tasks")
    which.add_argument("--deepsea-figure", metavar="PNG", help="draw docs/results.md's DeepSea scaling figure to PNG")
    which.add_argument("--explorers-figure", metavar="PNG", help="draw the explorer by task summary's runs to PNG")
    args = parser.parse_args(argv)
    index = Path(args.ledger_dir) / _index_read_by(args)
    if not index.is_file():
        parser.error(f"{index} is missing: a ledger folder holds {LEDGER_INDEX}, {EXPLORERS_INDEX} and {DEEPSEA_INDEX}")
    if args.deepsea_figure:
        print(f"wrote {render_deepsea_figure(args.ledger_dir, args.deepsea_figure)}")
    elif args.explorers_figure:
        print(f"wrote {render_explorers_figure(args.ledger_dir, args.explorers_figure)}")
    elif args.seeds:
        print(render_seeds_table(args.ledger_dir))
    elif args.deepsea:
        print(render_deepsea_table(args.ledger_dir))
    elif args.explorers:
        print(render_explorers_table(args.ledger_dir))
    elif args.across:
        print(render_across_table(args.ledger_dir))
    else:
        print(render_results_table(args.ledger_dir))


def _index_read_by(args: argparse.Namespace) -> str:
    """The index file the chosen table or figure is rendered from."""
    if args.deepsea or args.deepsea_figure:
        return DEEPSEA_INDEX
    if args.explorers or args.across or args.explorers_figure:
        return EXPLORERS_INDEX
    return LEDGER_INDEX


if __name__ == "__main__":
    main()
