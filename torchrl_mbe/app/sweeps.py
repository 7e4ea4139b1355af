"""Sweeps whose jobs differ only in ``seed``, run as populations: what ``hydra/launcher=population`` launches.

``python train.py -m seed=0,1,2,3,4 hydra/launcher=population`` asks Hydra for five
jobs; :func:`group_seeds` turns them into one, ``seed=0 population=5``, which trains the
five agents as one batched program (:mod:`torchrl_mbe.app.population`) and writes each
member's run directory under the job's (``<sweep dir>/0/seed0`` ... ``seed4``). The
launcher itself (``hydra_plugins/torchrl_mbe_launcher``) is Hydra's sequential one with
this grouping in front.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from omegaconf import DictConfig, open_dict

from torchrl_mbe.app.config import ConfigError, check_config

__all__ = ["group_seeds", "trains_together"]


def group_seeds(job_overrides: Sequence[Sequence[str]], can_group: Callable[[list[str]], bool]) -> list[list[str]]:
    """The jobs of a sweep with each run of consecutive seeds, all else equal, as one ``population=N`` job.

    Jobs that set every override alike but ``seed=<int>`` form a group; each run of
    consecutive seeds in it (``0,1,2`` of ``seed=0,1,2,5``) becomes one job
    ``seed=<first> population=<n>`` where ``can_group`` accepts those overrides (it
    says whether the config trains in populations: a prioritized buffer does not).
    Everything else stays as it was: a lone seed, a job without a ``seed=`` override,
    one that sets ``population`` itself, a seed listed twice, a population
    ``can_group`` refuses. A group's jobs take the place of its first job.

    Examples:
        >>> from torchrl_mbe.app.sweeps import group_seeds
        >>> jobs = [[f"buffer={b}", f"seed={s}"] for b in ("uniform", "prioritized") for s in (0, 1, 2, 5)]
        >>> for job in group_seeds(jobs, can_group=lambda overrides: "buffer=prioritized" not in overrides):
        ...     print(" ".join(job))
        buffer=uniform seed=0 population=3
        buffer=uniform seed=5
        buffer=prioritized seed=0
        buffer=prioritized seed=1
        buffer=prioritized seed=2
        buffer=prioritized seed=5
    """
    groups: dict[tuple[str, ...], dict[int, list[str]]] = {}  # the other overrides -> each seed's job
    grouped: list[
        list[str] | tuple[str, ...]
    ] = []  # a job left as it is, or the key of its group (first member's place)
    for overrides in job_overrides:
        seed, others = _split_seed(overrides)
        repeated = seed in groups.get(others, {})
        if seed is None or repeated or any(_key(override) == "population" for override in others):
            grouped.append(list(overrides))
            continue
        if others not in groups:
            groups[others] = {}
            grouped.append(others)
        groups[others][seed] = list(overrides)
    jobs = []
    for entry in grouped:
        jobs.extend([entry] if isinstance(entry, list) else _population_jobs(list(entry), groups[entry], can_group))
    return jobs


def trains_together(cfg: DictConfig) -> bool:
    """Whether a job's composed config (``population=N`` set, Hydra's node included) passes every check.

    A config that fails for a reason of its own fails the same way as single runs,
    with its one line, when they start.
    """
    cfg = cfg.copy()
    with open_dict(cfg):
        cfg.pop("hydra", None)  # what Hydra's run_job removes before the task sees the config
    try:
        check_config(cfg)
    except ConfigError:
        return False
    return True


def _population_jobs(
    others: list[str], jobs_by_seed: dict[int, list[str]], can_group: Callable[[list[str]], bool]
) -> list[list[str]]:
    jobs = []
    for first, size in _consecutive_runs(sorted(jobs_by_seed)):
        population = [*others, f"seed={first}", f"population={size}"]
        if size > 1 and can_group(population):
            jobs.append(population)
        else:
            jobs.extend(jobs_by_seed[seed] for seed in range(first, first + size))
    return jobs


def _consecutive_runs(seeds: list[int]) -> list[tuple[int, int]]:
    """``(first, length)`` of each run of consecutive integers in sorted ``seeds``: ``[0, 1, 2, 5]`` -> ``[(0, 3), (5, 1)]``."""
    runs: list[tuple[int, int]] = []
    for seed in seeds:
        if runs and runs[-1][0] + runs[-1][1] == seed:
            runs[-1] = (runs[-1][0], runs[-1][1] + 1)
        else:
            runs.append((seed, 1))
    return runs


def _split_seed(overrides: Sequence[str]) -> tuple[int | None, tuple[str, ...]]:
    """A job's ``seed=<int>`` (None without one) and its other overrides."""
    positions = [position for position, override in enumerate(overrides) if _key(override) == "seed"]
    value = overrides[positions[0]].split("=", 1)[1] if len(positions) == 1 else ""
    if not value.isdigit():
        return None, tuple(overrides)
    return int(value), tuple(override for position, override in enumerate(overrides) if position != positions[0])


def _key(override: str) -> str:
    return override.split("=", 1)[0]
