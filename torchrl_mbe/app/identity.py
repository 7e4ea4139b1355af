"""How a run is named and fingerprinted: its method label, env and seeds names, and its ``config_id``."""

from __future__ import annotations

import hashlib
import json

from omegaconf import DictConfig, OmegaConf

from torchrl_mbe.app.explorers import explorer_of
from torchrl_mbe.rundir import EXPLORATION_PREFIX

__all__ = ["config_differences", "config_id", "method_name", "seeds_name", "with_size"]


def method_name(cfg: DictConfig) -> str:
    """The name runs are grouped by in reports: ``dqn+gaussian``, ``explore:oracle``, ``reinforce``, ...

    Runs that never update the Q-network (``algo.updates_per_frame=0``, the
    exploration-only experiment) are named ``explore:<explorer>``. REINFORCE
    explores by sampling its policy, so the exploration group does not apply to it.
    """
    if cfg.algo.name == "reinforce":
        return "reinforce"
    learns = cfg.algo.updates_per_frame > 0
    label = explorer_of(cfg.exploration).method_label(cfg, learns=learns)
    return f"{cfg.algo.name}+{label}" if learns else EXPLORATION_PREFIX + label


def with_size(env: str, size: int | None) -> str:
    """An env's name with its size, if it has one: what run directories and summaries call it.

    Examples:
        >>> from torchrl_mbe.app.identity import with_size
        >>> with_size("DeepSea", 20), with_size("mountaincar", None)
        ('DeepSea-20', 'mountaincar')
    """
    return env if size is None else f"{env}-{size}"


def seeds_name(seed: int, population: int) -> str:
    """What a run directory is called after its seeds: ``seed3``, or a population's ``seeds0-4``.

    Examples:
        >>> from torchrl_mbe.app.identity import seeds_name
        >>> seeds_name(3, 1), seeds_name(0, 5)
        ('seed3', 'seeds0-4')
    """
    return f"seed{seed}" if population == 1 else f"seeds{seed}-{seed + population - 1}"


# Keys a resumed run may change: budgets, evaluation, logging and placement.
_RESUMABLE_CHANGES = ("resume", "train", "eval", "logger", "progress_bar", "device", "torch_threads", "compile")


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


def config_id(cfg: DictConfig) -> str:
    """A short fingerprint of everything that shapes a run's result except its seed.

    Runs with the same ``config_id`` ran the same experiment; the report groups by it.
    A setting added since runs were first fingerprinted counts only when it differs
    from the value that changes nothing (:data:`_ADDED_SETTINGS`), so a run of an older
    version keeps its id.
    """
    settings = _flatten(OmegaConf.to_container(cfg, resolve=True))
    shaping = {
        key: value
        for key, value in settings.items()
        if key != "seed" and key.split(".")[0] not in _PLACEMENT and _ADDED_SETTINGS.get(key, _NOT_ADDED) != value
    }
    return hashlib.sha1(json.dumps(shaping, sort_keys=True, default=str).encode()).hexdigest()[:8]


# Keys that change where and how a run is shown, or how seeds share a process, not what a run (a member) computes.
_PLACEMENT = (
    "resume",
    "logger",
    "progress_bar",
    "device",
    "torch_threads",
    "compile",
    "tag",
    "population",
    "processes",
)

# Settings added after torchrl-mbe 0.2.0, with their values that change nothing that version computed.
_ADDED_SETTINGS = {"env.size": None, "dynamics.output": "delta", "match_observation": True}
_NOT_ADDED = object()


def _flatten(tree: dict, prefix: str = "") -> dict:
    flat = {}
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            flat.update(_flatten(value, name + "."))
        else:
            flat[name] = value
    return flat
