"""Losses: ``DynamicsLoss``, the dynamics model's TorchRL ``LossModule`` (the Q side uses TorchRL's ``DQNLoss``)."""

from torchrl_mbe.objectives.dynamics import DynamicsLoss

__all__ = ["DynamicsLoss"]
