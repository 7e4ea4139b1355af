"""The run's environments, built from the ``env`` config: training, evaluation and final envs are one task."""

from __future__ import annotations

from omegaconf import DictConfig
from torchrl.data import TensorSpec
from torchrl.envs import EnvBase

from torchrl_mbe.envs import make_env

__all__ = ["config_observation_spec", "env_options", "make_run_env"]


def make_run_env(cfg: DictConfig, *, num_envs: int, seed: int, num_members: int | None = None) -> EnvBase:
    """The configured env (``cfg.env``, on ``cfg.device``), ``num_envs`` copies seeded from ``seed``.

    With ``population=M > 1`` the batch is ``(num_envs, M)``: ``num_envs`` copies per member
    (``(num_envs, num_members)`` for a batch that holds ``num_members`` of them).
    """
    batch = num_envs if cfg.population == 1 else (num_envs, num_members or cfg.population)
    return make_env(cfg.env.name, num_envs=batch, seed=seed, device=cfg.device, **env_options(cfg.env))


def env_options(env: DictConfig) -> dict:
    """The env's keyword arguments that the ``env`` config sets: ``gym.make``'s ``make_kwargs``, DeepSea's ``size``."""
    return {**env.make_kwargs, **({"size": env.size} if env.size is not None else {})}


def config_observation_spec(cfg: DictConfig) -> TensorSpec:
    """The observation spec of the env ``cfg.env`` describes."""
    return make_env(cfg.env.name, **env_options(cfg.env)).observation_spec["observation"]
