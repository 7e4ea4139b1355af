"""True dynamics ("oracle") of MountainCar-v0, written as torch operations.

Used to separate model error from the exploration rule in experiments: it
honours the dynamics contract (reads ``observation`` and ``action``, writes
``predicted_observation``), so it drops into :class:`~torchrl_mbe.NoveltyPlanner`
in place of a learned :class:`~torchrl_mbe.DynamicsModel`.
"""
from __future__ import annotations

import torch
from tensordict import NestedKey, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.data import TensorSpec

from torchrl_mbe.dynamics import action_indices, num_discrete_actions

__all__ = ["MOUNTAINCAR", "mountaincar_step", "MountainCarDynamics"]

MOUNTAINCAR = {
    "min_position": -1.2,
    "max_position": 0.6,
    "max_speed": 0.07,
    "goal_position": 0.5,
    "force": 0.001,
    "gravity": 0.0025,
}
"""MountainCar-v0's constants, as in gymnasium's ``MountainCarEnv``."""


def mountaincar_step(observation: torch.Tensor, action_index: torch.Tensor) -> torch.Tensor:
    """One MountainCar-v0 step for a batch: ``(..., 2)`` observations, ``(...)`` action indices.

    Mirrors gymnasium's ``MountainCarEnv.step`` (push left / none / right, gravity
    along the ``cos(3x)`` hill, speed clipped, inelastic left wall).
    """
    position, velocity = observation.unbind(-1)
    push = (action_index.to(observation.dtype) - 1) * MOUNTAINCAR["force"]
    velocity = velocity + push - MOUNTAINCAR["gravity"] * torch.cos(3 * position)
    velocity = velocity.clamp(-MOUNTAINCAR["max_speed"], MOUNTAINCAR["max_speed"])
    position = (position + velocity).clamp(MOUNTAINCAR["min_position"], MOUNTAINCAR["max_position"])
    at_left_wall = (position <= MOUNTAINCAR["min_position"]) & (velocity < 0)
    velocity = torch.where(at_left_wall, torch.zeros_like(velocity), velocity)
    return torch.stack([position, velocity], -1)


class MountainCarDynamics(TensorDictModuleBase):
    """MountainCar-v0's exact dynamics as a dynamics module (no parameters to learn).

    Args:
        action_spec (OneHot or Categorical): how ``action`` is encoded.

    Keyword Args:
        observation_key (NestedKey): defaults to ``"observation"``.
        action_key (NestedKey): defaults to ``"action"``.
        out_key (NestedKey): defaults to ``"predicted_observation"``.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl.data import Categorical
        >>> from torchrl_mbe.oracle import MountainCarDynamics
        >>> oracle = MountainCarDynamics(Categorical(3))
        >>> td = TensorDict({"observation": torch.tensor([-0.5, 0.0]), "action": torch.tensor(2)}, [])
        >>> oracle(td)["predicted_observation"]
        tensor([-0.4992,  0.0008])
    """

    def __init__(
        self,
        action_spec: TensorSpec,
        *,
        observation_key: NestedKey = "observation",
        action_key: NestedKey = "action",
        out_key: NestedKey = "predicted_observation",
    ) -> None:
        super().__init__()
        num_discrete_actions(action_spec)
        self.action_spec = action_spec
        self.in_keys = [observation_key, action_key]
        self.out_keys = [out_key]

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        observation_key, action_key = self.in_keys
        action_index = action_indices(tensordict.get(action_key), self.action_spec)
        tensordict.set(self.out_keys[0], mountaincar_step(tensordict.get(observation_key), action_index))
        return tensordict
