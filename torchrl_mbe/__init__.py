"""DQN with model-based exploration (Gou & Liu) as TorchRL components.

The exploring steps of an epsilon-greedy DQN are planned: a learned dynamics
network predicts the next state of every discrete action, a novelty scorer
fitted to the last F visited states scores the predictions, and the agent takes
the action leading to the rarest one.

The public names are imported on first use, so that ``python -m torchrl_mbe.report``
starts without loading torch and TorchRL.
"""
from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "BatchedMountainCarEnv": "torchrl_mbe.batched_env",
    "DynamicsLoss": "torchrl_mbe.objectives",
    "DynamicsModel": "torchrl_mbe.dynamics",
    "GaussianKernelNovelty": "torchrl_mbe.density",
    "ModelBasedExplorationPolicy": "torchrl_mbe.exploration",
    "NoveltyPlanner": "torchrl_mbe.planner",
    "RollingGaussianDensity": "torchrl_mbe.density",
    "RollingWindowNovelty": "torchrl_mbe.density",
    "SUPPORTED_ENVS": "torchrl_mbe.envs",
    "make_env": "torchrl_mbe.envs",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module 'torchrl_mbe' has no attribute {name!r}")
    return getattr(importlib.import_module(_EXPORTS[name]), name)


def __dir__() -> list[str]:
    return __all__
