"""The ledger: the recorded runs behind the README's results table, and the table rendered from them.

``docs/runs/`` holds the ``summary.json`` of every run the table cites (each with its
``record``: commit, machine, versions, command) and ``ledger.json``, one entry per row: the
task, its kind of reward, the folder of its runs and the command that trains it. The numbers
come from the summaries only: a run of ``exploration=egreedy`` counts as e-greedy, any other
as the default explorer. ``python -m torchrl_mbe.report.ledger docs/runs`` prints the table;
a test fails when README.md's copy differs.
"""

from __future__ import annotations

import json
import statistics
import sys
from collections.abc import Sequence
from pathlib import Path

__all__ = ["LEDGER_INDEX", "render_results_table"]

LEDGER_INDEX = "ledger.json"
EGREEDY = "dqn+egreedy"
HEADER = (
    "| task | reward | default explorer solved | e-greedy solved | median frames to solved (default) "
    "| median seconds to solved (default, its seeds at once) | commit | command |"
)


def render_results_table(ledger_dir: str | Path) -> str:
    """The README's results table, one row per ``ledger.json`` entry, from the summaries under ``ledger_dir``.

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
        | Toy-v0 | sparse | 2/3 | not run | 2,000 | 20 | 0123456 | `python train.py env=toy` |
    """
    ledger_dir = Path(ledger_dir)
    entries = json.loads((ledger_dir / LEDGER_INDEX).read_text())
    rows = [_row(entry, _summaries(ledger_dir / entry["runs"])) for entry in entries]
    return "\n".join([HEADER, "| --- " * HEADER.count(" | ") + "| --- |", *rows])


def _summaries(runs_dir: Path) -> list[dict]:
    return [json.loads(path.read_text()) for path in sorted(runs_dir.rglob("summary.json"))]


def _row(entry: dict, summaries: Sequence[dict]) -> str:
    default = [s for s in summaries if s["method"] != EGREEDY]
    egreedy = [s for s in summaries if s["method"] == EGREEDY]
    solved = [s for s in default if s["solved"]]
    commits = sorted({s["record"]["commit"][:7] for s in summaries})
    cells = [
        entry["task"],
        entry["reward"],
        _solved(default),
        _solved(egreedy),
        _median([s["solved_at_frames"] for s in solved]),
        _median([s["solved_at_wall_time_s"] for s in solved]),
        ", ".join(commits),
        f"`{entry['command']}`",
    ]
    return "| " + " | ".join(cells) + " |"


def _solved(summaries: Sequence[dict]) -> str:
    if not summaries:
        return "not run"
    return f"{sum(bool(s['solved']) for s in summaries)}/{len(summaries)}"


def _median(values: Sequence[float]) -> str:
    return f"{statistics.median(values):,.0f}" if values else "–"


if __name__ == "__main__":
    print(render_results_table(sys.argv[1] if len(sys.argv) > 1 else "docs/runs"))
