"""``make_env``: discrete-action tasks (gymnasium's, or the registry's torch-only DeepSea) wrapped the way a DQN needs them."""

from __future__ import annotations

import math
from typing import Any, Literal

import torch
from torchrl.envs import (
    Compose,
    DoubleToFloat,
    DTypeCastTransform,
    EnvBase,
    InitTracker,
    RewardSum,
    StepCounter,
    TransformedEnv,
)

from torchrl_mbe.envs.gym_batch import GymBatchEnv
from torchrl_mbe.envs.observations import make_gymnasium, wrap_gymnasium
from torchrl_mbe.envs.registry import TASKS, resolve_env_id, task_of

__all__ = ["dqn_transforms", "make_env"]


def make_env(
    name: str,
    *,
    num_envs: int | tuple[int, ...] = 1,
    backend: Literal["gym", "torch"] | None = None,
    seed: int | None = None,
    device: torch.device | str = "cpu",
    **env_kwargs: Any,
) -> TransformedEnv:
    """An environment (or a batch of ``num_envs`` copies) ready for DQN.

    Transforms: float observations (``DoubleToFloat``), ``StepCounter``
    (``step_count``), ``InitTracker`` (``is_init``) and ``RewardSum``
    (``episode_reward``, the running return). Actions are one-hot.

    Backends:

    * ``"gym"``: one ``GymWrapper`` of the gymnasium env (its observation as
      :func:`~torchrl_mbe.envs.observations.make_gymnasium` flattens it), or for ``num_envs > 1`` a
      :class:`~torchrl_mbe.envs.gym_batch.GymBatchEnv` of that batch shape (the
      episodes a ``SerialEnv`` of ``GymEnv`` copies plays, stepped without a
      TorchRL wrapper per copy). Not a ``ParallelEnv``: a classic-control or Box2D
      step costs microseconds, far less than the inter-process traffic, so worker
      processes do not pay off (and this project targets 2-core machines).
    * ``"torch"``: the copies step together as tensor operations (the
      registry's ``Task.torch_env``:
      :class:`~torchrl_mbe.envs.mountaincar.BatchedMountainCarEnv`,
      :class:`~torchrl_mbe.envs.cartpole.BatchedCartPoleEnv`,
      :class:`~torchrl_mbe.envs.acrobot.BatchedAcrobotEnv`,
      :class:`~torchrl_mbe.envs.deepsea.BatchedDeepSeaEnv`); batch size
      ``(num_envs,)`` even for one copy. The only backend of a torch-only task (DeepSea).

    The returned env's own ``state_dict`` holds only its transforms' (none of
    these keep any); a torch backend's whole state is ``env.base_env.state_dict()``
    (see :class:`~torchrl_mbe.envs.batched.BatchedTorchEnv`). The transforms' per-step
    entries (``step_count``, ``is_init``, ``episode_reward``) live in the tensordict
    carried from step to step, not in the env.

    The default is ``"torch"`` when the task has a torch implementation and
    ``num_envs > 1`` or no gymnasium version, ``"gym"`` otherwise (so
    ``make_env(name)`` of a gymnasium task is a ``GymWrapper``).

    Args:
        name (str): a short name of :data:`~torchrl_mbe.envs.registry.TASKS` or a gymnasium id.

    Keyword Args:
        num_envs (int or tuple of int): number of environment copies, or their batch
            shape (a population's ``(num_envs, M)``). Defaults to 1.
        backend (str, optional): ``"gym"`` or ``"torch"``; see above.
        seed (int, optional): seeds the environment (copies get distinct seeds).
        device (torch.device): where the env's tensors live. Defaults to CPU.
        **env_kwargs: keyword arguments of the task: its torch implementation's
            (DeepSea's ``size``, ``mapping_seed``, ...), or with the gym backend
            ``gym.make``'s (FrozenLake's ``is_slippery``, ...).

    Examples:
        >>> from torchrl_mbe import make_env
        >>> env = make_env("mountaincar", seed=0)
        >>> env.observation_spec["observation"].shape, env.action_spec.space.n
        (torch.Size([2]), 3)
        >>> type(make_env("mountaincar", num_envs=8).base_env).__name__, make_env("cartpole", num_envs=2).batch_size
        ('BatchedMountainCarEnv', torch.Size([2]))
        >>> make_env("deepsea", num_envs=16, seed=0, size=20).observation_spec["observation"].shape
        torch.Size([16, 400])
        >>> make_env("lunarlander", num_envs=(2, 3), seed=0).rollout(5, break_when_any_done=False).shape
        torch.Size([2, 3, 5])
        >>> make_env("FrozenLake8x8-v1", is_slippery=False).observation_spec["observation"].shape  # one-hot cells, as floats
        torch.Size([64])
        >>> make_env("MiniGrid-DoorKey-5x5-v0", num_envs=2).observation_spec["observation"].shape  # 7x7x3 codes and 4 directions
        torch.Size([2, 151])
        >>> make_env("Pendulum-v1")
        Traceback (most recent call last):
        ...
        ValueError: Pendulum-v1 has a Box(-2.0, 2.0, (1,), float32) action space; model-based exploration plans over one discrete action set (a Discrete action space).
    """
    batch_shape = (num_envs,) if isinstance(num_envs, int) else tuple(num_envs)
    if not batch_shape or min(batch_shape) < 1:
        raise ValueError(f"num_envs must be a positive integer (or a shape of them), got {num_envs}.")
    env_id = resolve_env_id(name)
    task = task_of(env_id)
    torch_env = task.torch_env if task is not None else None
    gymnasium = task is None or task.gymnasium
    if backend is None:
        backend = "torch" if torch_env is not None and (math.prod(batch_shape) > 1 or not gymnasium) else "gym"
    if backend == "torch":
        if torch_env is None:
            with_torch = sorted(t.env_id for t in TASKS.values() if t.torch_env is not None)
            raise ValueError(f"No torch implementation of {env_id}; torch backends exist for {with_torch}.")
        base_env = torch_env(num_envs, device=device, **env_kwargs)
    elif backend == "gym" and not gymnasium:
        raise ValueError(f"{env_id} has no gymnasium version; it runs with backend='torch' only.")
    elif backend == "gym":
        base_env = _gym_env(env_id, batch_shape, device, env_kwargs)
    else:
        raise ValueError(f"backend must be 'gym' or 'torch', got {backend!r}.")
    env = TransformedEnv(base_env, dqn_transforms(base_env.observation_spec["observation"].dtype))
    if seed is not None:
        env.set_seed(seed)
    return env


def dqn_transforms(observation_dtype: torch.dtype = torch.float32) -> Compose:
    """The transforms :func:`make_env` puts on every env: float32 observations, ``step_count``, ``is_init``, ``episode_reward``.

    A float64 observation is cast by ``DoubleToFloat``, any other (the one-hot
    integers of a ``Discrete`` observation) by ``DTypeCastTransform``.
    """
    if observation_dtype in (torch.float32, torch.float64):
        to_float = DoubleToFloat()
    else:
        to_float = DTypeCastTransform(observation_dtype, torch.float32, in_keys=["observation"])
    return Compose(to_float, StepCounter(), InitTracker(), RewardSum())


def _gym_env(
    env_id: str, batch_shape: tuple[int, ...], device: torch.device | str, make_kwargs: dict[str, Any]
) -> EnvBase:
    """TorchRL's ``GymWrapper`` of :func:`~torchrl_mbe.envs.observations.make_gymnasium`'s env for ``(1,)``, else a ``GymBatchEnv`` of ``batch_shape``."""
    if batch_shape == (1,):
        return wrap_gymnasium(make_gymnasium(env_id, **make_kwargs), device=device)
    return GymBatchEnv(env_id, batch_shape, device=device, make_kwargs=make_kwargs)
