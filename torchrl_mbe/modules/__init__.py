"""TorchRL modules: novelty scorers, the dynamics models, the planner and the exploration policies."""

from torchrl_mbe.modules.dynamics import DynamicsModel
from torchrl_mbe.modules.exploration import AnnealedEGreedyModule, ModelBasedExplorationPolicy, check_eps_schedule
from torchrl_mbe.modules.networks import init_linear_layers, make_per_action_mlp
from torchrl_mbe.modules.normalization import Standardize
from torchrl_mbe.modules.novelty import (
    DiagonalGaussianDensity,
    GaussianKernelNovelty,
    KernelDensityNovelty,
    KNearestNovelty,
    RollingGaussianDensity,
    RollingWindowNovelty,
    VisitCounts,
)
from torchrl_mbe.modules.planner import NoveltyPlanner
from torchrl_mbe.modules.table import TableActionValue, TableNoveltyValue, TransitionTable

__all__ = [
    "AnnealedEGreedyModule",
    "DiagonalGaussianDensity",
    "DynamicsModel",
    "GaussianKernelNovelty",
    "KNearestNovelty",
    "KernelDensityNovelty",
    "ModelBasedExplorationPolicy",
    "NoveltyPlanner",
    "RollingGaussianDensity",
    "RollingWindowNovelty",
    "Standardize",
    "TableActionValue",
    "TableNoveltyValue",
    "TransitionTable",
    "VisitCounts",
    "check_eps_schedule",
    "init_linear_layers",
    "make_per_action_mlp",
]
