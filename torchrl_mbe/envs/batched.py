"""The bases of the torch-batched envs.

* :class:`BatchedTorchEnv` is what every torch-batched task shares: a batch of
  copies stepped together as tensors, one-hot actions, a float32 reward, the done
  flags, a seeded CPU generator, and a ``state_dict`` that holds the env's whole
  state (so a run can be stopped and resumed exactly);
* :class:`BatchedClassicControlEnv` adds a gymnasium classic-control task's
  float64 physical state, its time limit and its start states. A task subclass
  says how many actions it has, the bounds of its observation, and supplies three
  hooks: the start states, one physics step, and the observation read from a state.
"""

from __future__ import annotations

import numbers
from abc import abstractmethod
from collections.abc import Sequence
from typing import Any, ClassVar

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, OneHot, TensorSpec, Unbounded
from torchrl.envs import EnvBase

__all__ = ["BatchedClassicControlEnv", "BatchedTorchEnv"]


class BatchedTorchEnv(EnvBase):
    """Copies of one discrete-action task stepped together as torch tensors, whose whole state ``state_dict`` holds.

    A subclass sets :attr:`num_actions`, calls :meth:`_make_spec` with its
    observation spec, keeps the state of its copies in registered (persistent)
    buffers and draws its randomness from ``self._generator``, a CPU
    :class:`torch.Generator` (so a seed gives the same episodes on every device).

    ``state_dict()`` then holds everything the next steps and resets depend on:
    those buffers and, as extra state, the generator's state. Loading it into a
    freshly built env of the same batch and arguments (any seed, any device) makes
    that env go on exactly as the saved one would. Its tensors are the live
    buffers, so copy it (or ``torch.save`` it) before stepping on. A
    :class:`~torchrl.envs.TransformedEnv` saves only its transforms' state:
    save its ``base_env.state_dict()``.

    Args:
        num_envs (int or tuple of int): number of copies, or the env's whole
            ``batch_size`` (e.g. ``(4, 8)``); an int ``n`` gives ``batch_size`` ``(n,)``.

    Keyword Args:
        seed (int, optional): seeds ``self._generator``. Defaults to a seed drawn
            from torch's global generator (so ``torch.manual_seed`` makes it reproducible).
        device (torch.device): where the env's tensors live. Defaults to CPU.

    Examples:
        >>> import copy, torch
        >>> from torchrl_mbe.envs.cartpole import BatchedCartPoleEnv
        >>> env = BatchedCartPoleEnv(3, seed=0)
        >>> td = env.rand_step(env.reset())
        >>> saved = copy.deepcopy(env.state_dict())
        >>> sorted(saved)
        ['_extra_state', 'elapsed_steps', 'physical_state']
        >>> resumed = BatchedCartPoleEnv(3, seed=1)
        >>> _ = resumed.load_state_dict(saved)
        >>> action = td["next"].set("action", env.action_spec.rand())
        >>> torch.equal(resumed.step(action.clone())["next", "observation"], env.step(action)["next", "observation"])
        True
        >>> torch.equal(resumed.reset()["observation"], env.reset()["observation"])  # the same start-state draws
        True
    """

    num_actions: ClassVar[int]
    """Size of the discrete action set."""

    def __init__(
        self,
        num_envs: int | Sequence[int],
        *,
        seed: int | None = None,
        device: torch.device | str = "cpu",
    ) -> None:
        batch_size = torch.Size([int(num_envs)] if isinstance(num_envs, numbers.Integral) else num_envs)
        if not batch_size or min(batch_size) < 1:
            raise ValueError(f"num_envs must be positive (or a non-empty shape of positive sizes), got {num_envs}.")
        super().__init__(device=device, batch_size=batch_size)
        self._generator = torch.Generator()
        if seed is None:
            seed = int(torch.empty((), dtype=torch.int64).random_())
        self.set_seed(seed)

    def _make_spec(self, observation: TensorSpec) -> None:
        """Set the specs: ``observation`` (shaped ``(*batch_size, ...)``), one-hot int64 actions, reward, done flags."""
        batch, device = self.batch_size, self.device
        self.observation_spec = Composite(observation=observation, shape=batch, device=device)
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

    def get_extra_state(self) -> dict[str, Any]:
        """The generator's state, which ``state_dict`` saves beside the buffers."""
        return {"generator": self._generator.get_state()}

    def set_extra_state(self, state: dict[str, Any]) -> None:
        """Restore the generator's state (a CPU byte tensor, wherever the state dict was loaded to)."""
        self._generator.set_state(state["generator"].cpu())

    def _output(self, observation: torch.Tensor, terminated: torch.Tensor, truncated: torch.Tensor) -> TensorDictBase:
        """A step's or reset's output: ``observation`` and the ``(*batch_size, 1)`` flags, ``done`` = either."""
        return TensorDict(
            {
                "observation": observation,
                "done": terminated | truncated,
                "terminated": terminated,
                "truncated": truncated,
            },
            batch_size=self.batch_size,
            device=self.device,
        )


class BatchedClassicControlEnv(BatchedTorchEnv):
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
    that are done) restarts only those copies. Start states are drawn from the
    env's own CPU generator; ``state_dict`` holds the physical state, the step
    counts and that generator's state (see :class:`BatchedTorchEnv`).

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
        max_episode_steps = self.default_max_episode_steps if max_episode_steps is None else int(max_episode_steps)
        if max_episode_steps < 1:
            raise ValueError(f"max_episode_steps must be >= 1, got {max_episode_steps}.")
        super().__init__(num_envs, seed=seed, device=device)
        self.max_episode_steps = max_episode_steps
        low, high = torch.tensor(self.observation_low), torch.tensor(self.observation_high)
        shape = (*self.batch_size, len(low))
        self._make_spec(
            Bounded(low=low.expand(shape), high=high.expand(shape), dtype=torch.float32, device=self.device)
        )
        state = torch.zeros(*self.batch_size, self.state_size, dtype=torch.float64, device=self.device)
        self.register_buffer("physical_state", state)
        self.register_buffer("elapsed_steps", torch.zeros(self.batch_size, dtype=torch.int64, device=self.device))

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
        return self._output(self._observe(self.physical_state), not_done, not_done.clone())

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        state, reward, terminated = self._transition(self.physical_state, tensordict.get("action").argmax(-1))
        self.physical_state.copy_(state)
        self.elapsed_steps.add_(1)
        truncated = (self.elapsed_steps >= self.max_episode_steps).unsqueeze(-1)
        output = self._output(self._observe(self.physical_state), terminated.unsqueeze(-1), truncated)
        output.set("reward", reward.to(torch.float32).unsqueeze(-1))
        return output
