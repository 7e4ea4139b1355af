"""Figures and tables from finished runs: ``python -m torchrl_mbe.report RUNS_DIR [--out OUT_DIR]``.

Every directory under ``RUNS_DIR`` (at any depth, so Hydra multirun sweeps work)
holding a ``summary.json`` is one run (:mod:`torchrl_mbe.report.runs` reads them).
The output directory gets ``results.md`` and, per env, ``frames_to_solved_<env>.png``,
``greedy_evaluations_<env>.png``, ``learning_curves_<env>.png`` and ``coverage_<env>.png``;
with DeepSea at two or more sizes, also ``scaling_DeepSea.png`` (episodes to solved against N).
"""

from __future__ import annotations

import argparse
import logging
from collections.abc import Sequence
from pathlib import Path

from torchrl_mbe.report.runs import RunFormatError, load_runs
from torchrl_mbe.report.tables import write_report

__all__ = ["main"]


def _positive_int(text: str) -> int:
    if not text.isdigit() or int(text) < 1:
        raise argparse.ArgumentTypeError(f"{text!r} is not a positive integer")
    return int(text)


def main(argv: Sequence[str] | None = None) -> None:
    """The ``torchrl-mbe-report`` command: reads ``RUNS_DIR``, writes the report, prints its paths."""
    parser = argparse.ArgumentParser(prog="torchrl-mbe-report", description=__doc__.splitlines()[0])
    parser.add_argument("runs_dir", type=Path, metavar="RUNS_DIR", help="holds the run directories, at any depth")
    parser.add_argument("--out", type=Path, default=None, help="output directory (default: RUNS_DIR/report)")
    parser.add_argument(
        "--window", type=_positive_int, default=100, help="running-average window (default: 100 episodes)"
    )
    parser.add_argument(
        "--bins", type=_positive_int, default=20, help="coverage grid cells per dimension (default: 20)"
    )
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        runs = load_runs(args.runs_dir)
        written = write_report(runs, args.out or args.runs_dir / "report", window=args.window, bins=args.bins)
    except (RunFormatError, OSError) as err:
        raise SystemExit(f"torchrl-mbe-report: error: {err}") from None
    for path in written:
        print(path)
