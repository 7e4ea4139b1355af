"""A batch of gymnasium envs of any shape, stepped in one loop: the gym backend of :func:`~torchrl_mbe.make_env`."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl._utils import seed_generator  # private: the seed sequence SerialEnv gives its copies has no public name
from torchrl.envs import EnvBase

from torchrl_mbe.envs.observations import make_gymnasium, wrap_gymnasium

__all__ = ["GymBatchEnv"]


class GymBatchEnv(EnvBase):
    """Copies of one gymnasium task with any ``batch_size``, stepped one after another in a single Python loop.

    It computes what a :class:`~torchrl.envs.SerialEnv` of
    :class:`~torchrl.envs.GymEnv` copies computes (nested, one level per batch
    dimension): the same specs (:class:`~torchrl.envs.GymEnv`'s, expanded to the
    batch: one-hot actions, float32 reward ``(..., 1)``, the three done flags),
    the same seeds (copy ``i`` in row-major order is seeded as the ``i``-th
    ``GymEnv`` of such a nest, each seed drawn from the last by TorchRL's
    ``seed_generator``), hence the same episodes for the same actions; but it
    calls each ``gymnasium`` env directly, without a TorchRL wrapper and a
    TensorDict per copy, which makes a step several times cheaper
    (``bench/throughput.py --only gym_batch``).

    Resets may be partial (a ``"_reset"`` mask, as a
    :class:`~torchrl.collectors.Collector` passes for the copies that are done)
    and so may steps (a ``"_step"`` mask, as ``env.rollout(break_when_all_done=True)``
    passes): only the masked copies move; the others report their last
    observation. Gymnasium envs cannot be saved, so a checkpoint holds nothing of
    this env (see :mod:`torchrl_mbe.app.rollout`).

    Args:
        env_id (str): a gymnasium id with a ``Discrete`` action space.
        batch_size (int or tuple of int): number of copies, or the batch shape (a population's ``(num_envs, M)``).

    Keyword Args:
        device (torch.device): where the env's tensors live. Defaults to CPU.
        make_kwargs (dict, optional): ``gym.make``'s keyword arguments. Each copy is
            :func:`~torchrl_mbe.envs.observations.make_gymnasium`'s env (its
            observation flattened to what a DQN reads).

    Examples:
        >>> from torchrl_mbe.envs import GymBatchEnv
        >>> env = GymBatchEnv("CartPole-v1", (2, 3))
        >>> _ = env.set_seed(0)
        >>> env.rollout(4, break_when_any_done=False)["next", "observation"].shape
        torch.Size([2, 3, 4, 4])
    """

    def __init__(
        self,
        env_id: str,
        batch_size: int | Sequence[int],
        *,
        device: torch.device | str = "cpu",
        make_kwargs: dict[str, Any] | None = None,
    ) -> None:
        batch_size = torch.Size([batch_size] if isinstance(batch_size, int) else batch_size)
        super().__init__(batch_size=batch_size, device=device)
        self.envs = [make_gymnasium(env_id, **(make_kwargs or {})) for _ in range(math.prod(batch_size))]
        reference = wrap_gymnasium(self.envs[0])  # TorchRL's reading of the gymnasium spaces
        for spec in ("full_observation_spec", "full_action_spec", "full_reward_spec", "full_done_spec"):
            setattr(self, spec, getattr(reference, spec).expand(*batch_size).to(self.device))
        self._observations = [None] * len(self.envs)  # each copy's last gymnasium observation

    def copies(self) -> list[tuple[Any, Any]]:
        """Each copy's gymnasium env and last observation, in row-major order: what :meth:`adopt` takes."""
        return list(zip(self.envs, self._observations, strict=True))

    def adopt(self, copies: list[tuple[Any, Any]]) -> None:
        """Goes on with ``copies`` (another batch's, from :meth:`copies`) in place of its own, mid-episode.

        A population whose members left the batch keeps the others' episodes running this way.

        Examples:
            >>> from torchrl_mbe.envs import GymBatchEnv
            >>> env = GymBatchEnv("CartPole-v1", (2, 3))
            >>> _ = env.set_seed(0)
            >>> member_1 = [copy for index, copy in enumerate(env.copies()) if index % 3 == 1]  # column 1's copies
            >>> kept = GymBatchEnv("CartPole-v1", (2, 1))
            >>> kept.adopt(member_1)
            >>> kept.copies() == member_1
            True
        """
        if len(copies) != len(self.envs):
            raise ValueError(f"adopt expects {len(self.envs)} copies, got {len(copies)}.")
        self.envs, self._observations = (list(part) for part in zip(*copies, strict=True))

    def _set_seed(self, seed: int | None) -> None:
        """Not used: :meth:`set_seed` seeds each copy with a seed of its own."""

    def set_seed(self, seed: int | None = None, static_seed: bool = False) -> int | None:
        """Seeds (and resets) copy after copy as a ``SerialEnv`` of ``GymEnv`` does; returns the seed for a next env."""
        for index in range(len(self.envs)):
            self._reset_copies([index], seed=seed)
            if seed is not None and not static_seed:
                seed = seed_generator(seed)
        return seed

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        self._reset_copies(self._masked(tensordict, "_reset"))
        not_done = np.zeros(len(self.envs), dtype=bool)
        return self._output(not_done, not_done)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        actions = tensordict.get("action").reshape(len(self.envs), -1).argmax(-1).tolist()
        rewards = np.zeros(len(self.envs))
        terminated, truncated = np.zeros(len(self.envs), dtype=bool), np.zeros(len(self.envs), dtype=bool)
        for index in self._masked(tensordict, "_step"):
            self._observations[index], rewards[index], terminated[index], truncated[index], _ = self.envs[index].step(
                actions[index]
            )
        reward = torch.as_tensor(rewards, dtype=torch.float32, device=self.device).view(*self.batch_size, 1)
        return self._output(terminated, truncated).set("reward", reward)

    def _masked(self, tensordict: TensorDictBase | None, key: str) -> list[int]:
        """The flat indices of the copies a ``"_reset"``/``"_step"`` mask selects (all copies without one)."""
        mask = None if tensordict is None else tensordict.get(key, None)
        if mask is None:
            return list(range(len(self.envs)))
        return mask.reshape(len(self.envs)).nonzero().squeeze(-1).tolist()

    def _reset_copies(self, copies: list[int], seed: int | None = None) -> None:
        for index in copies:
            self._observations[index], _ = self.envs[index].reset(seed=seed)

    def _observation_tensor(self) -> torch.Tensor:
        """The copies' last observations as the spec encodes them (a ``Discrete`` space one-hot), ``(*batch_size, ...)``."""
        observations = np.asarray(self._observations)
        return self.observation_spec["observation"].encode(
            observations.reshape(*self.batch_size, *observations.shape[1:])
        )

    def _output(self, terminated: np.ndarray, truncated: np.ndarray) -> TensorDictBase:
        """A step's or reset's output: the observations and the ``(*batch_size, 1)`` flags, ``done`` = either."""
        # torch.tensor copies the arrays: the two flags never share memory
        terminated, truncated = (
            torch.tensor(f, device=self.device).view(*self.batch_size, 1) for f in (terminated, truncated)
        )
        return TensorDict(
            {
                "observation": self._observation_tensor(),
                "done": terminated | truncated,
                "terminated": terminated,
                "truncated": truncated,
            },
            batch_size=self.batch_size,
            device=self.device,
        )
