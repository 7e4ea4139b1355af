"""Checks on the training app's config: one clear error per bad value."""
from __future__ import annotations

from omegaconf import DictConfig, OmegaConf

__all__ = ["ConfigError", "check_config", "config_differences"]

_POSITIVE_INTEGERS = (
    "train.episodes",
    "buffer.size",
    "algo.batch_size",
    "collector.frames_per_batch",
    "env.num_envs",
    "exploration.horizon",
    "dynamics.batch_size",
    "eval.every_frames",
    "train.checkpoint_every_frames",
)
_NON_NEGATIVE_NUMBERS = (
    "algo.learning_starts",
    "algo.updates_per_frame",
    "dynamics.learning_starts",
    "dynamics.updates_per_frame",
    "eval.episodes",
    "eval.final_episodes",
    "optim.q_lr",
    "optim.dynamics_lr",
    "algo.lr",
    "algo.weight_std",
)
_LAYER_LISTS = ("algo.num_cells", "dynamics.num_cells")

# Keys a resumed run may change: budgets, evaluation, logging and placement.
_RESUMABLE_CHANGES = ("resume", "train", "eval", "logger", "progress_bar", "device", "torch_threads")


class ConfigError(ValueError):
    """A config value the app cannot run with; the message names the key and what is accepted."""


def check_config(cfg: DictConfig) -> None:
    """Raises :class:`ConfigError` for the first bad value of ``cfg``.

    Examples:
        >>> from omegaconf import OmegaConf
        >>> from torchrl_mbe.config import check_config
        >>> check_config(OmegaConf.create({"exploration": {"name": "gaussian", "window": 1}}))
        Traceback (most recent call last):
        ...
        torchrl_mbe.config.ConfigError: exploration.window=1: the novelty window needs at least 2 states (the paper uses 50).
    """
    window = OmegaConf.select(cfg, "exploration.window")
    if window is not None and (not isinstance(window, int) or window < 2):
        raise ConfigError(f"exploration.window={window}: the novelty window needs at least 2 states (the paper uses 50).")
    for key in _POSITIVE_INTEGERS:
        value = OmegaConf.select(cfg, key)
        if value is not None and (not isinstance(value, int) or value < 1):
            raise ConfigError(f"{key}={value}: expected a positive integer.")
    for key in _NON_NEGATIVE_NUMBERS:
        value = OmegaConf.select(cfg, key)
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float)) or value < 0):
            raise ConfigError(f"{key}={value}: expected a number >= 0.")
    for key in _LAYER_LISTS:
        cells = OmegaConf.select(cfg, key)
        if cells is not None and (len(cells) == 0 or any(not isinstance(c, int) or c < 1 for c in cells)):
            raise ConfigError(f"{key}={list(cells)}: expected a non-empty list of positive layer sizes.")
    num_envs, frames_per_batch = OmegaConf.select(cfg, "env.num_envs"), OmegaConf.select(cfg, "collector.frames_per_batch")
    if OmegaConf.select(cfg, "algo.name") == "reinforce" and num_envs not in (None, 1):
        raise ConfigError(f"env.num_envs={num_envs}: algo=reinforce plays one episode at a time; use env.num_envs=1.")
    if num_envs and frames_per_batch and frames_per_batch % num_envs:
        raise ConfigError(
            f"collector.frames_per_batch={frames_per_batch} must be a multiple of env.num_envs={num_envs}."
        )


def config_differences(saved: dict, current: DictConfig) -> list[str]:
    """``key: saved -> current`` for every setting that differs, budgets and logging aside."""
    now = OmegaConf.to_container(current, resolve=True)
    saved_flat, now_flat = _flatten(saved), _flatten(now)
    keys = sorted(set(saved_flat) | set(now_flat))
    return [
        f"{key}: {saved_flat.get(key, '<absent>')} -> {now_flat.get(key, '<absent>')}"
        for key in keys
        if key.split(".")[0] not in _RESUMABLE_CHANGES and saved_flat.get(key) != now_flat.get(key)
    ]


def _flatten(tree: dict, prefix: str = "") -> dict:
    flat = {}
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            flat.update(_flatten(value, name + "."))
        else:
            flat[name] = value
    return flat
