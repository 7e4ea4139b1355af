"""The base of the torch-batched classic-control envs: everything but the task's physics.

:class:`BatchedClassicControlEnv` holds a float64 physical state for every copy,
counts steps for the time limit, resets all or only some copies and draws start
states from its own seeded generator. A task subclass says how many actions it
has, the bounds of its observation, and supplies three hooks: the start states,
one physics step, and the observation read from a state.
"""
from __future__ import annotations

from abc import abstractmethod
from collections.abc import Sequence
from typing import ClassVar

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, OneHot, Unbounded
from torchrl.envs import EnvBase

__all__ = ["BatchedClassicControlEnv"]


class BatchedClassicControlEnv(EnvBase):
    """Many copies of a gymnasium classic-control task stepped together as torch tensors.

    A subclass sets the class attributes below and implements :meth:`_initial_state`,
    :meth:`_transition` and (unless the observation is the state itself)
    :meth:`_observe`. The env then behaves as ``gymnasium.make`` builds the task,
    wrapped in :class:`~torchrl.envs.GymEnv`:

    * ``terminated`` is the task's own rule, ``truncated`` is set after
      ``max_episode_steps`` steps (the ``TimeLimit`` wrapper), ``done`` = either;
    * ``observation`` is float32 and ``reward`` float32 ``(..., 1)``; actions are
      one-hot int64 (as ``GymEnv`` encodes a ``Discrete`` space).

    The state stays float64 between steps, as gymnasium keeps it, so
    trajectories agree with gymnasium's. Resets may be partial: a ``"_reset"``
    mask (what a :class:`~torchrl.collectors.Collector` passes for the sub-envs
    that are done) restarts only those copies. Start states are drawn from a CPU
    :class:`torch.Generator` owned by the env, so a seed gives the same episodes
    on every device.

    Args:
        num_envs (int or tuple of int): number of copies, or the env's whole
            ``batch_size`` (e.g. ``(4, 8)``); an int ``n`` gives ``batch_size`` ``(n,)``.

    Keyword Args:
        max_episode_steps (int, optional): truncation horizon. Defaults to the
            task's gymnasium registration (:attr:`default_max_episode_steps`).
        seed (int, optional): seeds the start states. Defaults to a seed drawn
            from torch's global generator (so ``torch.manual_seed`` makes it reproducible).
        device (torch.device): where the env's tensors live. Defaults to CPU.

    Attributes:
        physical_state (Tensor): the float64 ``(*batch_size, state_size)`` state
            the observations are computed from.
        elapsed_steps (Tensor): steps since each copy's last reset.

    Examples:
        >>> import torch
        >>> from torchrl_mbe.envs.cartpole import BatchedCartPoleEnv
        >>> env = BatchedCartPoleEnv((2, 3), seed=0)
        >>> td = env.rand_step(env.reset())
        >>> env.elapsed_steps
        tensor([[1, 1, 1],
                [1, 1, 1]])
        >>> reset = torch.tensor([[True, False, False], [False, False, True]]).unsqueeze(-1)
        >>> _ = env.reset(td["next"].set("_reset", reset))
        >>> env.elapsed_steps
        tensor([[0, 1, 1],
                [1, 1, 0]])
    """

    num_actions: ClassVar[int]
    """Size of the discrete action set."""
    state_size: ClassVar[int]
    """Length of the physical state vector."""
    observation_low: ClassVar[tuple[float, ...]]
    """Lower bounds of the observation (gymnasium's ``observation_space.low``)."""
    observation_high: ClassVar[tuple[float, ...]]
    """Upper bounds of the observation (gymnasium's ``observation_space.high``)."""
    default_max_episode_steps: ClassVar[int]
    """The time limit gymnasium registers the task with."""

    def __init__(
        self,
        num_envs: int | Sequence[int],
        *,
        max_episode_steps: int | None = None,
        seed: int | None = None,
        device: torch.device | str = "cpu",
    ) -> None:
        batch_size = torch.Size([num_envs] if isinstance(num_envs, int) else num_envs)
        max_episode_steps = self.default_max_episode_steps if max_episode_steps is None else int(max_episode_steps)
        if not batch_size or min(batch_size) < 1 or max_episode_steps < 1:
            raise ValueError(
                f"num_envs must be positive (or a non-empty shape of positive sizes) and max_episode_steps >= 1, "
                f"got {num_envs} and {max_episode_steps}."
            )
        super().__init__(device=device, batch_size=batch_size)
        self.max_episode_steps = max_episode_steps
        self._make_spec()
        state = torch.zeros(*batch_size, self.state_size, dtype=torch.float64, device=self.device)
        self.register_buffer("physical_state", state, persistent=False)
        self.register_buffer(
            "elapsed_steps", torch.zeros(batch_size, dtype=torch.int64, device=self.device), persistent=False
        )
        self._generator = torch.Generator()
        if seed is None:
            seed = int(torch.empty((), dtype=torch.int64).random_())
        self.set_seed(seed)

    @abstractmethod
    def _initial_state(self) -> torch.Tensor:
        """Start states of every copy: float64 ``(*batch_size, state_size)``, drawn from ``self._generator``."""

    @abstractmethod
    def _transition(
        self, state: torch.Tensor, action_index: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """One step from float64 ``state`` under ``action_index``: the next state, the reward and ``terminated``."""

    def _observe(self, state: torch.Tensor) -> torch.Tensor:
        """The float32 observation of a state; by default the state itself."""
        return state.to(torch.float32)

    def _make_spec(self) -> None:
        batch, device = self.batch_size, self.device
        low, high = torch.tensor(self.observation_low), torch.tensor(self.observation_high)
        size = len(low)
        self.observation_spec = Composite(
            observation=Bounded(
                low=low.expand(*batch, size), high=high.expand(*batch, size), dtype=torch.float32, device=device
            ),
            shape=batch,
            device=device,
        )
        self.action_spec = OneHot(self.num_actions, shape=(*batch, self.num_actions), dtype=torch.int64, device=device)
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
        start = self._initial_state().to(self.device)
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
        state, reward, terminated = self._transition(self.physical_state, tensordict.get("action").argmax(-1))
        self.physical_state.copy_(state)
        self.elapsed_steps.add_(1)
        truncated = (self.elapsed_steps >= self.max_episode_steps).unsqueeze(-1)
        output = self._output(terminated.unsqueeze(-1), truncated)
        output.set("reward", reward.to(torch.float32).unsqueeze(-1))
        return output

    def _output(self, terminated: torch.Tensor, truncated: torch.Tensor) -> TensorDictBase:
        return TensorDict(
            {
                "observation": self._observe(self.physical_state),
                "done": terminated | truncated,
                "terminated": terminated,
                "truncated": truncated,
            },
            batch_size=self.batch_size,
            device=self.device,
        )
