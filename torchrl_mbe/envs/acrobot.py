"""Acrobot-v1 in torch: its physics and the batched env built on it.

* :func:`acrobot_step` is gymnasium's ``AcrobotEnv.step`` physics for a batch of
  states (the book dynamics, one RK4 step of 0.2 s, angles wrapped, velocities clipped);
* :func:`acrobot_observation` and :func:`acrobot_terminated` read a state as gymnasium does;
* :class:`BatchedAcrobotEnv` steps N copies of Acrobot-v1 together as tensor
  operations (no gymnasium in the loop).
"""

from __future__ import annotations

import math

import torch

from torchrl_mbe.envs.batched import BatchedClassicControlEnv

__all__ = ["ACROBOT", "BatchedAcrobotEnv", "acrobot_observation", "acrobot_step", "acrobot_terminated"]

ACROBOT = {
    "dt": 0.2,
    "link_length_1": 1.0,
    "link_mass_1": 1.0,
    "link_mass_2": 1.0,
    "link_com_pos_1": 0.5,
    "link_com_pos_2": 0.5,
    "link_moi": 1.0,
    "gravity": 9.8,
    "max_vel_1": 4 * math.pi,
    "max_vel_2": 9 * math.pi,
    "avail_torque": (-1.0, 0.0, 1.0),
    "reset_bound": 0.1,  # every state dimension starts uniform in (-0.1, 0.1)
    "max_episode_steps": 500,  # Acrobot-v1's registration, gymnasium/envs/__init__.py
}
"""Acrobot-v1's constants, as in ``AcrobotEnv`` and its ``_dsdt`` (gymnasium/envs/classic_control/acrobot.py)."""


def _derivatives(state: torch.Tensor, torque: torch.Tensor) -> torch.Tensor:
    """``AcrobotEnv._dsdt`` with ``book_or_nips = "book"``, term for term (the torque's own derivative, 0, left out)."""
    m1, m2 = ACROBOT["link_mass_1"], ACROBOT["link_mass_2"]
    l1 = ACROBOT["link_length_1"]
    lc1, lc2 = ACROBOT["link_com_pos_1"], ACROBOT["link_com_pos_2"]
    I1 = I2 = ACROBOT["link_moi"]
    g = ACROBOT["gravity"]
    pi = math.pi
    theta1, theta2, dtheta1, dtheta2 = state.unbind(-1)
    cos_theta2, sin_theta2 = torch.cos(theta2), torch.sin(theta2)
    d1 = m1 * lc1**2 + m2 * (l1**2 + lc2**2 + 2 * l1 * lc2 * cos_theta2) + I1 + I2
    d2 = m2 * (lc2**2 + l1 * lc2 * cos_theta2) + I2
    phi2 = m2 * lc2 * g * torch.cos(theta1 + theta2 - pi / 2.0)
    phi1 = (
        -m2 * l1 * lc2 * dtheta2**2 * sin_theta2
        - 2 * m2 * l1 * lc2 * dtheta2 * dtheta1 * sin_theta2
        + (m1 * lc1 + m2 * l1) * g * torch.cos(theta1 - pi / 2)
        + phi2
    )
    ddtheta2 = (torque + d2 / d1 * phi1 - m2 * l1 * lc2 * dtheta1**2 * sin_theta2 - phi2) / (
        m2 * lc2**2 + I2 - d2**2 / d1
    )
    ddtheta1 = -(d2 * ddtheta2 + phi1) / d1
    return torch.stack([dtheta1, dtheta2, ddtheta1, ddtheta2], -1)


def _wrap(x: torch.Tensor, low: float, high: float) -> torch.Tensor:
    """gymnasium's ``wrap``: shift ``x`` by whole periods ``high - low`` into ``[low, high]``."""
    period = high - low
    below = torch.ceil((low - x) / period).clamp_min(0)
    above = torch.ceil((x - high) / period).clamp_min(0)
    return x + period * (below - above)


def acrobot_step(state: torch.Tensor, action_index: torch.Tensor) -> torch.Tensor:
    """One Acrobot-v1 step for a batch: ``(..., 4)`` states ``[theta1, theta2, dtheta1, dtheta2]``, ``(...)`` actions.

    Mirrors gymnasium's ``AcrobotEnv.step``: torque ``action_index - 1``, one
    fourth-order Runge-Kutta step of ``dt = 0.2`` s through the book dynamics (as
    gymnasium's ``rk4`` over ``[0, dt]``), angles wrapped into ``[-pi, pi]``,
    velocities clipped to ``4 pi`` and ``9 pi``. Pass float64 states to agree with
    gymnasium to rounding.

    Examples:
        >>> import torch
        >>> from torchrl_mbe.envs.acrobot import acrobot_step
        >>> acrobot_step(torch.zeros(2, 4, dtype=torch.float64), torch.tensor([0, 2]))  # at rest, torques -1, +1
        tensor([[ 0.0133, -0.0343,  0.1287, -0.3345],
                [-0.0133,  0.0343, -0.1287,  0.3345]], dtype=torch.float64)
    """
    torque = torch.tensor(ACROBOT["avail_torque"], dtype=state.dtype, device=state.device)[action_index]
    dt = ACROBOT["dt"]
    dt2 = dt / 2.0
    k1 = _derivatives(state, torque)
    k2 = _derivatives(state + dt2 * k1, torque)
    k3 = _derivatives(state + dt2 * k2, torque)
    k4 = _derivatives(state + dt * k3, torque)
    theta1, theta2, dtheta1, dtheta2 = (state + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)).unbind(-1)
    return torch.stack(
        [
            _wrap(theta1, -math.pi, math.pi),
            _wrap(theta2, -math.pi, math.pi),
            dtheta1.clamp(-ACROBOT["max_vel_1"], ACROBOT["max_vel_1"]),
            dtheta2.clamp(-ACROBOT["max_vel_2"], ACROBOT["max_vel_2"]),
        ],
        -1,
    )


def acrobot_observation(state: torch.Tensor) -> torch.Tensor:
    """The float32 observation ``[cos t1, sin t1, cos t2, sin t2, dt1, dt2]`` of ``(..., 4)`` states."""
    theta1, theta2, dtheta1, dtheta2 = state.unbind(-1)
    angles = [torch.cos(theta1), torch.sin(theta1), torch.cos(theta2), torch.sin(theta2)]
    return torch.stack([*angles, dtheta1, dtheta2], -1).to(torch.float32)


def acrobot_terminated(state: torch.Tensor) -> torch.Tensor:
    """Whether the tip is above the bar: ``-cos(t1) - cos(t1 + t2) > 1``, for ``(..., 4)`` states."""
    theta1, theta2 = state[..., 0], state[..., 1]
    return -torch.cos(theta1) - torch.cos(theta2 + theta1) > 1.0


class BatchedAcrobotEnv(BatchedClassicControlEnv):
    """``num_envs`` copies of gymnasium's Acrobot-v1 stepped together as torch tensors.

    The physics is :func:`acrobot_step` applied to a float64 ``(*batch_size, 4)``
    state (the two joint angles and their velocities; gymnasium computes in
    float64 too, so trajectories agree with it); the rest follows Acrobot-v1 as
    ``gymnasium.make`` builds it:

    * every state dimension starts uniform in ``[-0.1, 0.1]``, rounded to float32
      (as gymnasium draws it);
    * reward -1 per step, 0 on the terminating step;
    * ``terminated`` once the tip swings above the bar (:func:`acrobot_terminated`),
      ``truncated`` after ``max_episode_steps`` steps (500);
    * ``observation`` is :func:`acrobot_observation` (float32), actions are
      one-hot int64 (torque -1, 0, +1).

    Batching, partial resets, seeding and ``state_dict`` are those of
    :class:`~torchrl_mbe.envs.batched.BatchedClassicControlEnv`.

    Args:
        num_envs (int or tuple of int): number of copies (``batch_size`` ``(num_envs,)``), or the batch shape.

    Keyword Args:
        max_episode_steps (int): truncation horizon. Defaults to 500 (Acrobot-v1).
        seed (int, optional): seeds the start states. Defaults to a seed drawn
            from torch's global generator (so ``torch.manual_seed`` makes it reproducible).
        device (torch.device): where the env's tensors live. Defaults to CPU.

    Examples:
        >>> from torchrl.envs.utils import check_env_specs
        >>> from torchrl_mbe.envs.acrobot import BatchedAcrobotEnv
        >>> env = BatchedAcrobotEnv(4, max_episode_steps=100, seed=0)
        >>> check_env_specs(env)
        >>> rollout = env.rollout(100)
        >>> rollout.shape, rollout["observation"].shape, rollout["action"].dtype
        (torch.Size([4, 100]), torch.Size([4, 100, 6]), torch.int64)
        >>> bool(rollout["next", "truncated"][:, -1].all())  # random torques rarely lift the tip
        True
    """

    num_actions = 3
    state_size = 4
    # AcrobotEnv.observation_space: cosines and sines in [-1, 1], velocities within their clipping bounds.
    observation_high = (1.0, 1.0, 1.0, 1.0, ACROBOT["max_vel_1"], ACROBOT["max_vel_2"])
    observation_low = tuple(-bound for bound in observation_high)
    default_max_episode_steps = ACROBOT["max_episode_steps"]

    def _initial_state(self) -> torch.Tensor:
        bound = ACROBOT["reset_bound"]
        uniform = torch.rand(*self.batch_size, 4, generator=self._generator, dtype=torch.float64)
        return (-bound + 2 * bound * uniform).to(torch.float32).to(torch.float64)

    def _observe(self, state: torch.Tensor) -> torch.Tensor:
        return acrobot_observation(state)

    def _transition(
        self, state: torch.Tensor, action_index: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        next_state = acrobot_step(state, action_index)
        terminated = acrobot_terminated(next_state)
        return next_state, terminated.to(torch.float32) - 1, terminated
