"""``population=M processes=P``: the members split into ``P`` populations trained side by side, one process each.

A population's members run as one batched program on one core
(:mod:`torchrl_mbe.app.population`); on a machine of several cores the members are
split into ``P`` parts of consecutive seeds (sizes differing by at most one), each
trained in its own process, in its own directory ``<run_dir>/seeds<a>-<b>`` (a part of
one seed writes ``<run_dir>/seed<a>``, a single run's directory). Each part keeps its own
checkpoint, so ``resume=true`` resumes every part. The config is checked, and matched to
the observation, once, before the split.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from omegaconf import DictConfig

from torchrl_mbe.app.identity import seeds_name
from torchrl_mbe.app.population import StopOnInterrupt, population_summary
from torchrl_mbe.app.run import LAUNCHING_COMMAND, hydra_command

__all__ = ["split_members", "train_in_processes"]

log = logging.getLogger(__name__)


def split_members(seed: int, population: int, processes: int) -> list[tuple[int, int]]:
    """``(first seed, size)`` of each part: ``min(processes, population)`` runs of consecutive seeds, the larger first.

    Examples:
        >>> from torchrl_mbe.app.processes import split_members
        >>> split_members(0, 5, 2), split_members(10, 2, 4)
        ([(0, 3), (3, 2)], [(10, 1), (11, 1)])
    """
    parts = min(processes, population)
    sizes = [population // parts + (part < population % parts) for part in range(parts)]
    firsts = [seed + sum(sizes[:part]) for part in range(parts)]
    return list(zip(firsts, sizes))


def train_in_processes(
    cfg: DictConfig, run_dir: Path, loop: Callable[[DictConfig, Path], dict], processes: int
) -> dict:
    """Runs ``loop(part_cfg, part_dir)`` for each of ``processes`` parts of ``cfg.population``, each in its own process;
    returns the population's summary.

    Raises:
        SystemExit: a Ctrl-C stopped the parts (each saved its checkpoint); the message says how to continue.
    """
    parts = split_members(cfg.seed, cfg.population, processes)
    log.info(
        "population=%d in %d processes side by side: seeds %s",
        cfg.population,
        len(parts),
        ", ".join(_seeds(first, size) for first, size in parts),
    )
    command = hydra_command()  # the parts' summaries record the command that launched them
    context = multiprocessing.get_context("spawn")  # a fresh interpreter: no forked torch threads or locks
    with StopOnInterrupt(), ProcessPoolExecutor(len(parts), mp_context=context) as pool:
        futures = [
            pool.submit(_train_part, loop, _part_config(cfg, first, size), run_dir / seeds_name(first, size), command)
            for first, size in parts
        ]
        summaries = [future.result() for future in futures]
    if any("interrupted" in summary for summary in summaries):
        raise SystemExit(
            f"Interrupted; every part saved its checkpoint in {run_dir}. "
            f"Continue with: python train.py <same overrides> resume=true hydra.run.dir={run_dir}"
        )
    return _merged(summaries, [run_dir / seeds_name(first, size) for first, size in parts])


def _part_config(cfg: DictConfig, first: int, size: int) -> DictConfig:
    part = cfg.copy()
    part.seed, part.population, part.processes = first, size, 1
    part.progress_bar = False  # the parts log their evaluations and stops; bars would interleave
    return part


def _seeds(first: int, size: int) -> str:
    return str(first) if size == 1 else f"{first}-{first + size - 1}"


def _train_part(loop: Callable[[DictConfig, Path], dict], cfg: DictConfig, run_dir: Path, command: str | None) -> dict:
    """A part's process: its log lines (prefixed with its seeds, also in its ``train.log``), its command, then its loop."""
    if command is not None:
        os.environ[LAUNCHING_COMMAND] = command  # this process's own environment: the launching one keeps its
    run_dir.mkdir(parents=True, exist_ok=True)
    prefix = f"[seeds {_seeds(cfg.seed, cfg.population)}] %(asctime)s %(name)s %(levelname)s - %(message)s"
    logging.basicConfig(level=logging.INFO, format=prefix)
    file_handler = logging.FileHandler(run_dir / "train.log")
    file_handler.setFormatter(logging.Formatter(prefix))
    logging.getLogger().addHandler(file_handler)
    try:
        return loop(cfg, run_dir)
    except SystemExit as interrupted:
        return {"interrupted": str(interrupted)}


def _merged(summaries: list[dict], part_dirs: list[Path]) -> dict:
    """The parts' summaries as one population's (each member's under ``"members"``, as one process returns it)."""
    members, run_dirs = [], []
    for summary, part_dir in zip(summaries, part_dirs):
        members += summary.get("members", [summary])
        run_dirs += summary.get("run_dirs", [str(part_dir)])
    return population_summary(members, run_dirs)
