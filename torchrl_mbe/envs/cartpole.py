"""CartPole-v1 in torch: its physics and the batched env built on it.

* :func:`cartpole_step` is gymnasium's ``CartPoleEnv.step`` physics for a batch of states;
* :func:`cartpole_terminated` is its termination rule (cart off the track or pole past 12 degrees);
* :class:`BatchedCartPoleEnv` steps N copies of CartPole-v1 together as tensor
  operations (no gymnasium in the loop).
"""

from __future__ import annotations

import math

import torch

from torchrl_mbe.envs.batched import BatchedClassicControlEnv

__all__ = ["CARTPOLE", "BatchedCartPoleEnv", "cartpole_step", "cartpole_terminated"]

CARTPOLE = {
    "gravity": 9.8,
    "masscart": 1.0,
    "masspole": 0.1,
    "length": 0.5,  # half the pole's length
    "force_mag": 10.0,
    "tau": 0.02,  # seconds between state updates (Euler integrator)
    "theta_threshold_radians": 12 * 2 * math.pi / 360,
    "x_threshold": 2.4,
    "reset_bound": 0.05,  # every state dimension starts uniform in (-0.05, 0.05)
    "max_episode_steps": 500,  # CartPole-v1's registration, gymnasium/envs/__init__.py
}
"""CartPole-v1's constants, as in ``CartPoleEnv.__init__`` and ``reset``
(gymnasium/envs/classic_control/cartpole.py)."""

_TOTAL_MASS = CARTPOLE["masspole"] + CARTPOLE["masscart"]
_POLEMASS_LENGTH = CARTPOLE["masspole"] * CARTPOLE["length"]


def cartpole_step(state: torch.Tensor, action_index: torch.Tensor) -> torch.Tensor:
    """One CartPole-v1 step for a batch: ``(..., 4)`` states, ``(...)`` action indices (0 left, 1 right).

    Mirrors gymnasium's ``CartPoleEnv.step`` (the same expressions in the same
    order, Euler integration); pass float64 states to agree with it to rounding.

    Examples:
        >>> import torch
        >>> from torchrl_mbe.envs.cartpole import cartpole_step
        >>> cartpole_step(torch.zeros(2, 4, dtype=torch.float64), torch.tensor([0, 1]))
        tensor([[ 0.0000, -0.1951,  0.0000,  0.2927],
                [ 0.0000,  0.1951,  0.0000, -0.2927]], dtype=torch.float64)
    """
    x, x_dot, theta, theta_dot = state.unbind(-1)
    force = torch.where(action_index == 1, CARTPOLE["force_mag"], -CARTPOLE["force_mag"]).to(state.dtype)
    costheta = torch.cos(theta)
    sintheta = torch.sin(theta)
    temp = (force + _POLEMASS_LENGTH * torch.square(theta_dot) * sintheta) / _TOTAL_MASS
    thetaacc = (CARTPOLE["gravity"] * sintheta - costheta * temp) / (
        CARTPOLE["length"] * (4.0 / 3.0 - CARTPOLE["masspole"] * torch.square(costheta) / _TOTAL_MASS)
    )
    xacc = temp - _POLEMASS_LENGTH * thetaacc * costheta / _TOTAL_MASS
    tau = CARTPOLE["tau"]
    return torch.stack([x + tau * x_dot, x_dot + tau * xacc, theta + tau * theta_dot, theta_dot + tau * thetaacc], -1)


def cartpole_terminated(state: torch.Tensor) -> torch.Tensor:
    """Whether ``(..., 4)`` states end the episode: ``|x| > 2.4`` or ``|theta| > 12 degrees``."""
    x, theta = state[..., 0], state[..., 2]
    return (x.abs() > CARTPOLE["x_threshold"]) | (theta.abs() > CARTPOLE["theta_threshold_radians"])


class BatchedCartPoleEnv(BatchedClassicControlEnv):
    """``num_envs`` copies of gymnasium's CartPole-v1 stepped together as torch tensors.

    The physics is :func:`cartpole_step` applied to a float64
    ``(*batch_size, 4)`` state (cart position and velocity, pole angle and
    angular velocity; gymnasium computes in float64 too, so trajectories agree
    with it); the rest follows CartPole-v1 as ``gymnasium.make`` builds it:

    * every state dimension starts uniform in ``[-0.05, 0.05]``;
    * reward 1 per step, the terminating step included;
    * ``terminated`` once the cart leaves ``[-2.4, 2.4]`` or the pole tilts past
      12 degrees, ``truncated`` after ``max_episode_steps`` steps (500);
    * ``observation`` is the float32 state, actions are one-hot int64 (push left, push right).

    Batching, partial resets, seeding and ``state_dict`` are those of
    :class:`~torchrl_mbe.envs.batched.BatchedClassicControlEnv`.

    Args:
        num_envs (int or tuple of int): number of copies (``batch_size`` ``(num_envs,)``), or the batch shape.

    Keyword Args:
        max_episode_steps (int): truncation horizon. Defaults to 500 (CartPole-v1).
        seed (int, optional): seeds the start states. Defaults to a seed drawn
            from torch's global generator (so ``torch.manual_seed`` makes it reproducible).
        device (torch.device): where the env's tensors live. Defaults to CPU.

    Examples:
        >>> from torchrl.envs.utils import check_env_specs
        >>> from torchrl_mbe.envs.cartpole import BatchedCartPoleEnv
        >>> env = BatchedCartPoleEnv(4, seed=0)
        >>> check_env_specs(env)
        >>> rollout = env.rollout(100, break_when_any_done=False)
        >>> rollout.shape, rollout["observation"].dtype, rollout["action"].dtype
        (torch.Size([4, 100]), torch.float32, torch.int64)
        >>> bool(rollout["next", "terminated"][:, :100].any(1).all())  # random pushes drop the pole quickly
        True
    """

    num_actions = 2
    state_size = 4
    # CartPoleEnv.observation_space: twice the termination thresholds, unbounded velocities.
    observation_high = (2 * CARTPOLE["x_threshold"], math.inf, 2 * CARTPOLE["theta_threshold_radians"], math.inf)
    observation_low = tuple(-bound for bound in observation_high)
    default_max_episode_steps = CARTPOLE["max_episode_steps"]

    def _initial_state(self) -> torch.Tensor:
        bound = CARTPOLE["reset_bound"]
        uniform = torch.rand(*self.batch_size, 4, generator=self._generator, dtype=torch.float64)
        return -bound + 2 * bound * uniform

    def _transition(
        self, state: torch.Tensor, action_index: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        next_state = cartpole_step(state, action_index)
        return next_state, torch.ones(self.batch_size, device=self.device), cartpole_terminated(next_state)
