"""Losses: the dynamics model's ``DynamicsLoss`` and the value of novelty's ``NoveltyValueLoss``, TorchRL ``LossModule``s (the Q side uses TorchRL's ``DQNLoss``)."""

from torchrl_mbe.objectives.dynamics import DynamicsLoss
from torchrl_mbe.objectives.novelty_value import NoveltyValueLoss

__all__ = ["DynamicsLoss", "NoveltyValueLoss"]
