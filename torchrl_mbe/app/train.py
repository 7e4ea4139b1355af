"""``train(cfg)``: checks the config, then runs the configured algorithm's loop."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import torch
from omegaconf import DictConfig

from torchrl_mbe.app.config import check_config, register_configs
from torchrl_mbe.app.dqn import train_dqn
from torchrl_mbe.app.environments import config_observation_spec
from torchrl_mbe.app.observation import match_observation, named_on_command_line
from torchrl_mbe.app.processes import train_in_processes
from torchrl_mbe.app.reinforce import train_reinforce
from torchrl_mbe.app.replay import check_replay_fits
from torchrl_mbe.app.run import RunFinished
from torchrl_mbe.modules.observations import categorical_groups

__all__ = ["LOOPS", "default_processes", "run_loop", "train"]

log = logging.getLogger(__name__)

LOOPS = {"dqn": train_dqn, "reinforce": train_reinforce}
"""The training loop of each ``algo=`` option."""


def train(cfg: DictConfig, run_dir: str | Path | None = None) -> dict:
    """Trains the configured agent and returns the run's summary (``summary.json``).

    With ``population=M > 1`` it trains M agents together, each writing its own run
    directory (:mod:`torchrl_mbe.app.population`), in ``processes`` processes side by side
    (:mod:`torchrl_mbe.app.processes`), and returns the population's summary, each
    member's under ``"members"``.

    Every config value is checked before anything is built
    (:class:`~torchrl_mbe.app.config.ConfigError` names a bad one). The explorer then
    follows the env's observation where nobody chose otherwise
    (:func:`~torchrl_mbe.app.observation.match_observation`).

    Args:
        cfg (DictConfig): a config composed from ``conf/`` (see ``docs/usage.md``).
        run_dir (path, optional): where CSVs, checkpoints and the summary go;
            defaults to Hydra's output directory.
    """
    register_configs()  # the method_name resolver, where a launcher runs this job in a fresh process
    check_config(cfg)
    observation_spec = config_observation_spec(cfg)
    changes = match_observation(cfg, observation_spec, named_on_command_line())
    if changes:
        variables = len(categorical_groups(observation_spec))
        log.info(
            "One-hot observation (%d entries, %d categorical variable%s): %s. Name any of these on the command line, or match_observation=false, to choose otherwise.",
            observation_spec.shape[-1],
            variables,
            "s" * (variables > 1),
            ", ".join(changes),
        )
        check_config(cfg)
    run_dir = Path(run_dir) if run_dir is not None else Path(_hydra_output_dir())
    if cfg.algo.name == "dqn":  # every process's buffers together, before any part starts
        check_replay_fits(cfg.buffer, observation_spec.shape[-1], cfg.population, cfg.device, run_dir)
    processes = default_processes(cfg)
    if cfg.population > 1 and processes > 1:
        return train_in_processes(cfg, run_dir, run_loop, processes)
    return run_loop(cfg, run_dir)


def default_processes(cfg: DictConfig) -> int:
    """How many processes a population splits into: ``processes``, else one per CPU core, or one on a GPU.

    A GPU runs the whole population as one batched program; a process per core would
    give each part its own CUDA context and its own share of the same GPU.

    Examples:
        >>> import os
        >>> from omegaconf import OmegaConf
        >>> from torchrl_mbe.app.train import default_processes
        >>> default_processes(OmegaConf.create({"processes": None, "device": "cuda:0"}))
        1
        >>> default_processes(OmegaConf.create({"processes": None, "device": "cpu"})) == (os.cpu_count() or 1)
        True
        >>> default_processes(OmegaConf.create({"processes": 3, "device": "cuda"}))
        3
    """
    if cfg.processes:
        return cfg.processes
    return 1 if str(cfg.device).startswith("cuda") else os.cpu_count() or 1


def run_loop(cfg: DictConfig, run_dir: Path) -> dict:
    """Runs the loop of ``algo=`` on a checked config in this process (one part of a population split into processes)."""
    logging.getLogger("torchrl").setLevel(logging.WARNING)  # TorchRL announces every storage it initializes
    if cfg.torch_threads:
        torch.set_num_threads(cfg.torch_threads)
    # Adam's moments of parameters whose gradient is zero (dead ReLU units) decay into
    # subnormal floats, on which CPU arithmetic is many times slower: flushed to zero.
    torch.set_flush_denormal(True)
    torch.manual_seed(cfg.seed)
    try:
        return LOOPS[cfg.algo.name](cfg, run_dir)
    except RunFinished as finished:
        log.info(
            "%s already finished its budget (raise train.episodes or train.max_frames to continue); nothing changed.",
            run_dir,
        )
        return finished.summary


def _hydra_output_dir() -> str:
    from hydra.core.hydra_config import HydraConfig

    return HydraConfig.get().runtime.output_dir
