"""Test doubles for dynamics modules: hand-built predictions the tests know exactly."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase


class ShiftDynamics(TensorDictModuleBase):
    """Predicts ``s + shifts[a]``: the next state of each action is known exactly."""

    def __init__(self, shifts: torch.Tensor, one_hot: bool = True):
        super().__init__()
        self.shifts = shifts
        self.one_hot = one_hot
        self.in_keys = ["observation", "action"]
        self.out_keys = ["predicted_observation"]

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = tensordict["action"]
        index = action.long().argmax(-1) if self.one_hot else action
        tensordict["predicted_observation"] = tensordict["observation"] + self.shifts[index]
        return tensordict
