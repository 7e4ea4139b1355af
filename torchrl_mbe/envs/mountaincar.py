"""MountainCar-v0 in torch: its physics, the batched env built on it, and the oracle dynamics.

* :func:`mountaincar_step` is gymnasium's ``MountainCarEnv.step`` for a batch of states;
* :class:`BatchedMountainCarEnv` steps N copies of MountainCar-v0 together as tensor
  operations (no gymnasium in the loop);
* :class:`MountainCarDynamics` is the true dynamics as a dynamics module (the
  "oracle"): it separates model error from the exploration rule in experiments,
  since it honours the dynamics contract (reads ``observation`` and ``action``,
  writes ``predicted_observation``) and drops into
  :class:`~torchrl_mbe.NoveltyPlanner` in place of a learned
  :class:`~torchrl_mbe.DynamicsModel`.
"""

from __future__ import annotations

import torch

from torchrl_mbe.envs.batched import BatchedClassicControlEnv
from torchrl_mbe.modules.dynamics import ExactDynamics

__all__ = ["MOUNTAINCAR", "BatchedMountainCarEnv", "MountainCarDynamics", "mountaincar_step"]

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


class MountainCarDynamics(ExactDynamics):
    """MountainCar-v0's exact dynamics as a dynamics module (no parameters to learn).

    Args and keyword args: those of :class:`~torchrl_mbe.modules.dynamics.ExactDynamics`.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl.data import Categorical
        >>> from torchrl_mbe.envs.mountaincar import MountainCarDynamics
        >>> oracle = MountainCarDynamics(Categorical(3))
        >>> td = TensorDict({"observation": torch.tensor([-0.5, 0.0]), "action": torch.tensor(2)}, [])
        >>> oracle(td)["predicted_observation"]
        tensor([-0.4992,  0.0008])
    """

    def step(self, observation: torch.Tensor, action_index: torch.Tensor) -> torch.Tensor:
        return mountaincar_step(observation, action_index)


_START_POSITION_RANGE = (-0.6, -0.4)
"""gymnasium's MountainCar-v0 draws the start position uniformly from this range (velocity 0)."""


class BatchedMountainCarEnv(BatchedClassicControlEnv):
    """``num_envs`` copies of gymnasium's MountainCar-v0 stepped together as torch tensors.

    The physics is :func:`mountaincar_step` applied to a float64
    ``(*batch_size, 2)`` state (gymnasium computes in float64 too, so
    trajectories agree with it); the rest follows MountainCar-v0 as
    ``gymnasium.make`` builds it:

    * start position uniform in ``[-0.6, -0.4]``, velocity 0;
    * reward -1 per step;
    * ``terminated`` once position >= 0.5 with velocity >= 0, ``truncated`` after
      ``max_episode_steps`` steps (the ``TimeLimit`` wrapper), ``done`` = either;
    * ``observation`` is float32 (position, velocity), actions are one-hot int64
      (as :class:`~torchrl.envs.GymEnv` encodes a ``Discrete(3)`` space).

    Batching, partial resets, seeding and ``state_dict`` are those of
    :class:`~torchrl_mbe.envs.batched.BatchedClassicControlEnv`.

    TorchRL's per-call overhead is the same for one copy or a thousand, which is
    why this env collects many times faster than a :class:`~torchrl.envs.SerialEnv`
    of ``GymEnv`` (see ``bench/throughput.py``).

    Args:
        num_envs (int or tuple of int): number of copies (``batch_size`` ``(num_envs,)``), or the batch shape.

    Keyword Args:
        max_episode_steps (int): truncation horizon. Defaults to 200 (MountainCar-v0).
        seed (int, optional): seeds the start states. Defaults to a seed drawn
            from torch's global generator (so ``torch.manual_seed`` makes it reproducible).
        device (torch.device): where the env's tensors live. Defaults to CPU.

    Attributes:
        physical_state (Tensor): the float64 ``(*batch_size, 2)`` position and velocity
            the observations are rounded from.

    Examples:
        >>> from torchrl.envs.utils import check_env_specs
        >>> from torchrl_mbe.envs.mountaincar import BatchedMountainCarEnv
        >>> env = BatchedMountainCarEnv(4, seed=0)
        >>> check_env_specs(env)
        >>> rollout = env.rollout(200)
        >>> rollout.shape, rollout["observation"].dtype, rollout["action"].dtype
        (torch.Size([4, 200]), torch.float32, torch.int64)
        >>> bool(rollout["next", "truncated"][:, -1].all())  # random actions never reach the flag
        True
    """

    num_actions = 3
    state_size = 2
    observation_low = (MOUNTAINCAR["min_position"], -MOUNTAINCAR["max_speed"])
    observation_high = (MOUNTAINCAR["max_position"], MOUNTAINCAR["max_speed"])
    default_max_episode_steps = 200  # MountainCar-v0's registration, gymnasium/envs/__init__.py

    def _initial_state(self) -> torch.Tensor:
        low, high = _START_POSITION_RANGE
        position = torch.rand(self.batch_size, generator=self._generator, dtype=torch.float64)
        return torch.stack([low + (high - low) * position, torch.zeros_like(position)], -1)

    def _transition(
        self, state: torch.Tensor, action_index: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        next_state = mountaincar_step(state, action_index)
        position, velocity = next_state.unbind(-1)
        at_the_flag = (position >= MOUNTAINCAR["goal_position"]) & (velocity >= 0)  # not rolling back
        return next_state, torch.full(self.batch_size, -1.0, device=self.device), at_the_flag
