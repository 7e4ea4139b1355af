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
from tensordict import NestedKey, TensorDict, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.data import Bounded, Categorical, Composite, OneHot, TensorSpec, Unbounded
from torchrl.envs import EnvBase

from torchrl_mbe.modules.dynamics import action_indices, num_discrete_actions

__all__ = ["MOUNTAINCAR", "mountaincar_step", "MountainCarDynamics", "BatchedMountainCarEnv"]

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
        >>> from torchrl_mbe.envs.mountaincar import MountainCarDynamics
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


_START_POSITION_RANGE = (-0.6, -0.4)
"""gymnasium's MountainCar-v0 draws the start position uniformly from this range (velocity 0)."""


class BatchedMountainCarEnv(EnvBase):
    """``num_envs`` copies of gymnasium's MountainCar-v0 stepped together as torch tensors.

    The physics is :func:`mountaincar_step` applied to a
    ``(num_envs, 2)`` float64 state (gymnasium computes in float64 too, so
    trajectories agree with it); the rest follows MountainCar-v0 as
    ``gymnasium.make`` builds it:

    * start position uniform in ``[-0.6, -0.4]``, velocity 0;
    * reward -1 per step;
    * ``terminated`` once position >= 0.5 with velocity >= 0, ``truncated`` after
      ``max_episode_steps`` steps (the ``TimeLimit`` wrapper), ``done`` = either;
    * ``observation`` is float32 (position, velocity), actions are one-hot int64
      (as :class:`~torchrl.envs.GymEnv` encodes a ``Discrete(3)`` space).

    Resets may be partial: a ``"_reset"`` mask (what a
    :class:`~torchrl.collectors.Collector` passes for the sub-envs that are done)
    restarts only those copies. Start states are drawn from a CPU
    :class:`torch.Generator` owned by the env, so a seed gives the same episodes
    on every device.

    TorchRL's per-call overhead is the same for one copy or a thousand, which is
    why this env collects many times faster than a :class:`~torchrl.envs.SerialEnv`
    of ``GymEnv`` (see ``bench/throughput.py``).

    Args:
        num_envs (int): number of copies; the env's ``batch_size`` is ``(num_envs,)``.

    Keyword Args:
        max_episode_steps (int): truncation horizon. Defaults to 200 (MountainCar-v0).
        seed (int, optional): seeds the start states. Defaults to a seed drawn
            from torch's global generator (so ``torch.manual_seed`` makes it reproducible).
        device (torch.device): where the env's tensors live. Defaults to CPU.

    Attributes:
        physical_state (Tensor): the float64 ``(num_envs, 2)`` position and velocity
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

    def __init__(
        self,
        num_envs: int,
        *,
        max_episode_steps: int = 200,
        seed: int | None = None,
        device: torch.device | str = "cpu",
    ) -> None:
        if int(num_envs) < 1 or int(max_episode_steps) < 1:
            raise ValueError(
                f"num_envs and max_episode_steps must be >= 1, got {num_envs} and {max_episode_steps}."
            )
        super().__init__(device=device, batch_size=(int(num_envs),))
        self.max_episode_steps = int(max_episode_steps)
        self._make_spec()
        self.register_buffer(
            "physical_state", torch.zeros(*self.batch_size, 2, dtype=torch.float64, device=self.device), persistent=False
        )
        self.register_buffer(
            "elapsed_steps", torch.zeros(self.batch_size, dtype=torch.int64, device=self.device), persistent=False
        )
        goal = torch.tensor([MOUNTAINCAR["goal_position"], 0.0], dtype=torch.float64, device=self.device)
        self.register_buffer("goal_state", goal, persistent=False)
        self._generator = torch.Generator()
        if seed is None:
            seed = int(torch.empty((), dtype=torch.int64).random_())
        self.set_seed(seed)

    def _make_spec(self) -> None:
        batch, device = self.batch_size, self.device
        low = torch.tensor([MOUNTAINCAR["min_position"], -MOUNTAINCAR["max_speed"]])
        high = torch.tensor([MOUNTAINCAR["max_position"], MOUNTAINCAR["max_speed"]])
        self.observation_spec = Composite(
            observation=Bounded(
                low=low.expand(*batch, 2), high=high.expand(*batch, 2), dtype=torch.float32, device=device
            ),
            shape=batch,
            device=device,
        )
        self.action_spec = OneHot(3, shape=(*batch, 3), dtype=torch.int64, device=device)
        self.reward_spec = Unbounded(shape=(*batch, 1), dtype=torch.float32, device=device)
        flag = Categorical(2, shape=(*batch, 1), dtype=torch.bool, device=device)
        self.done_spec = Composite(
            done=flag, terminated=flag.clone(), truncated=flag.clone(), shape=batch, device=device
        )

    def _set_seed(self, seed: int | None) -> None:
        if seed is None:
            self._generator.seed()
        else:
            self._generator.manual_seed(int(seed))

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        reset = None if tensordict is None else tensordict.get("_reset", None)
        low, high = _START_POSITION_RANGE
        position = torch.rand(self.batch_size, generator=self._generator, dtype=torch.float64)
        start = torch.stack([low + (high - low) * position, torch.zeros_like(position)], -1).to(self.device)
        if reset is None:
            self.physical_state.copy_(start)
            self.elapsed_steps.zero_()
        else:
            reset = reset.reshape(self.batch_size)
            self.physical_state.copy_(torch.where(reset.unsqueeze(-1), start, self.physical_state))
            self.elapsed_steps.masked_fill_(reset, 0)
        not_done = torch.zeros(*self.batch_size, 1, dtype=torch.bool, device=self.device)
        return self._output(not_done, not_done.clone())

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = tensordict.get("action").argmax(-1)
        self.physical_state.copy_(mountaincar_step(self.physical_state, action))
        self.elapsed_steps.add_(1)
        terminated = (self.physical_state >= self.goal_state).all(-1, keepdim=True)  # at the flag, not rolling back
        truncated = (self.elapsed_steps >= self.max_episode_steps).unsqueeze(-1)
        output = self._output(terminated, truncated)
        output.set("reward", torch.full((*self.batch_size, 1), -1.0, device=self.device))
        return output

    def _output(self, terminated: torch.Tensor, truncated: torch.Tensor) -> TensorDictBase:
        return TensorDict(
            {
                "observation": self.physical_state.to(torch.float32),
                "done": terminated | truncated,
                "terminated": terminated,
                "truncated": truncated,
            },
            batch_size=self.batch_size,
            device=self.device,
        )
