"""DQN with model-based exploration (Gou & Liu) as TorchRL components.

The exploring steps of an epsilon-greedy DQN are planned: a learned dynamics
network predicts the next state of every discrete action, a novelty scorer
fitted to the last F visited states scores the predictions, and the agent takes
the action leading to the rarest one.
"""
from __future__ import annotations

from torchrl_mbe.density import GaussianKernelNovelty, RollingGaussianDensity, RollingWindowNovelty
from torchrl_mbe.dynamics import DynamicsModel
from torchrl_mbe.envs import SUPPORTED_ENVS, make_env
from torchrl_mbe.exploration import ModelBasedExplorationPolicy
from torchrl_mbe.objectives import DynamicsLoss
from torchrl_mbe.planner import NoveltyPlanner

__all__ = [
    "DynamicsLoss",
    "DynamicsModel",
    "GaussianKernelNovelty",
    "ModelBasedExplorationPolicy",
    "NoveltyPlanner",
    "RollingGaussianDensity",
    "RollingWindowNovelty",
    "SUPPORTED_ENVS",
    "make_env",
]
