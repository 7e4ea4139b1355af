"""The timing harness of every bench: variants timed in alternating blocks after warm-up, and the table printer.

Variants that are compared are timed block by block in turn, so a change of machine
load during a run hits them alike; each figure is a median over blocks.
"""

from __future__ import annotations

import math
import os
import statistics
import time
from collections.abc import Callable, Sequence

import torch

__all__ = ["median_seconds", "print_rows"]


def median_seconds(
    variants: dict[str, Callable[[], object]],
    *,
    repeats: int,
    warmup: int = 1,
    calls: int | None = None,
    min_block_s: float = 0.1,
    slow_call_s: float = math.inf,
) -> dict[str, float]:
    """Median seconds per call of each variant.

    Each variant is called ``warmup`` times untimed but the last; then ``repeats``
    rounds time a block of ``calls`` calls of every variant in turn (by default as
    many as the last warm-up call says fill ``min_block_s``). A variant whose last
    warm-up call took over ``slow_call_s`` is not repeated: that call is its figure.

    Examples:
        >>> from timing import median_seconds
        >>> sorted(median_seconds({"a": lambda: None, "b": lambda: sum(range(100))}, repeats=3, min_block_s=0.001))
        ['a', 'b']
    """
    last_call = {name: _seconds_of(variant, 1, untimed=max(warmup - 1, 0)) for name, variant in variants.items()}
    repeated = {name: variant for name, variant in variants.items() if last_call[name] <= slow_call_s}
    block = {name: calls or max(1, math.ceil(min_block_s / max(last_call[name], 1e-9))) for name in repeated}
    seconds = {name: [] for name in repeated}
    for _ in range(repeats):
        for name, variant in repeated.items():
            seconds[name].append(_seconds_of(variant, block[name]))
    return last_call | {name: statistics.median(values) for name, values in seconds.items()}


def _seconds_of(call: Callable[[], object], calls: int, untimed: int = 0) -> float:
    for _ in range(untimed):
        call()
    start = time.perf_counter()
    for _ in range(calls):
        call()
    return (time.perf_counter() - start) / calls


def print_rows(title: str, header: Sequence[str], rows: list[Sequence[str]]) -> None:
    """A titled table, columns right-aligned to their widest cell."""
    widths = [max(len(cell) for cell in column) for column in zip(header, *rows)]
    print(f"\n[{title}]")
    for row in (header, *rows):
        print("  " + "  ".join(cell.rjust(width) for cell, width in zip(row, widths)))


def print_machine_line() -> None:
    """The torch version, threads, CPUs and load at the start: what a bench's figures depend on."""
    print(
        f"torch {torch.__version__}, {torch.get_num_threads()} thread(s), {os.cpu_count()} CPUs, "
        f"1-minute load average {os.getloadavg()[0]:.2f} at start"
    )
