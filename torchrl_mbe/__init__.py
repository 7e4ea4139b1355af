"""DQN with model-based exploration (Gou & Liu) as TorchRL components.

The exploring steps of an epsilon-greedy DQN are planned: a learned dynamics
network predicts the next state of every discrete action, a novelty scorer
fitted to the last F visited states scores the predictions, and the agent takes
the action leading to the rarest one.

The components live in :mod:`torchrl_mbe.modules`, :mod:`torchrl_mbe.objectives`
and :mod:`torchrl_mbe.envs`; the Hydra app in :mod:`torchrl_mbe.app` and the
report in :mod:`torchrl_mbe.report` build on them (docs/architecture.md).
"""

from importlib.metadata import version as _version

from torchrl_mbe.envs import SUPPORTED_ENVS, BatchedMountainCarEnv, MountainCarDynamics, make_env
from torchrl_mbe.modules import (
    AnnealedEGreedyModule,
    DiagonalGaussianDensity,
    DynamicsModel,
    GaussianKernelNovelty,
    KernelDensityNovelty,
    KNearestNovelty,
    ModelBasedExplorationPolicy,
    NoveltyPlanner,
    RollingGaussianDensity,
    RollingWindowNovelty,
    TableActionValue,
    TableNoveltyValue,
    TransitionTable,
    VisitCounts,
)
from torchrl_mbe.objectives import DynamicsLoss, NoveltyValueLoss

__all__ = [
    "SUPPORTED_ENVS",
    "AnnealedEGreedyModule",
    "BatchedMountainCarEnv",
    "DiagonalGaussianDensity",
    "DynamicsLoss",
    "DynamicsModel",
    "GaussianKernelNovelty",
    "KNearestNovelty",
    "KernelDensityNovelty",
    "ModelBasedExplorationPolicy",
    "MountainCarDynamics",
    "NoveltyPlanner",
    "NoveltyValueLoss",
    "RollingGaussianDensity",
    "RollingWindowNovelty",
    "TableActionValue",
    "TableNoveltyValue",
    "TransitionTable",
    "VisitCounts",
    "make_env",
]

__version__ = _version("torchrl-mbe")
"""The installed version (pyproject.toml's ``version``)."""
