"""Environments: gymnasium discrete-action tasks wrapped the way a DQN needs them."""
from __future__ import annotations

import gymnasium as gym
import torch
from torchrl.envs import Compose, DoubleToFloat, GymEnv, InitTracker, RewardSum, StepCounter, TransformedEnv

__all__ = ["SUPPORTED_ENVS", "SOLVED_THRESHOLDS", "resolve_env_id", "make_env"]

SUPPORTED_ENVS = {
    "mountaincar": "MountainCar-v0",
    "lunarlander": "LunarLander-v3",
    "acrobot": "Acrobot-v1",
    "cartpole": "CartPole-v1",
}
"""Short names accepted everywhere (config files, ``make_env``) and their gymnasium ids."""

SOLVED_THRESHOLDS = {"MountainCar-v0": -110.0, "LunarLander-v3": 200.0, "Acrobot-v1": -100.0, "CartPole-v1": 475.0}
"""Average return over 100 episodes at which gymnasium calls each task solved."""


def _supported_list() -> str:
    return ", ".join(f"{alias} ({env_id})" for alias, env_id in SUPPORTED_ENVS.items())


def resolve_env_id(name: str) -> str:
    """The gymnasium id of a short name or id; one clear error for anything unsupported.

    Any registered gymnasium id with a discrete action space is accepted; the
    project is tested on the four of :data:`SUPPORTED_ENVS`.
    """
    env_id = SUPPORTED_ENVS.get(name.lower(), name)
    if env_id not in gym.registry:
        raise ValueError(f"Unknown environment {name!r}. Supported: {_supported_list()}.")
    action_space = gym.spec(env_id).make().action_space
    if not isinstance(action_space, gym.spaces.Discrete):
        raise ValueError(
            f"{env_id} has a {type(action_space).__name__} action space; model-based exploration "
            f"plans over a discrete action set. Supported: {_supported_list()}."
        )
    return env_id


def make_env(name: str, *, seed: int | None = None, device: torch.device | str = "cpu") -> TransformedEnv:
    """A ``TransformedEnv(GymEnv(...))`` ready for DQN.

    Transforms: float observations (``DoubleToFloat``), ``StepCounter``
    (``step_count``), ``InitTracker`` (``is_init``) and ``RewardSum``
    (``episode_reward``, the running return). Actions are one-hot.

    Args:
        name (str): a short name of :data:`SUPPORTED_ENVS` or a gymnasium id.

    Keyword Args:
        seed (int, optional): seeds the environment.
        device (torch.device): where the env's tensors live. Defaults to CPU.

    Examples:
        >>> from torchrl_mbe import make_env
        >>> env = make_env("mountaincar", seed=0)
        >>> env.observation_spec["observation"].shape, env.action_spec.space.n
        (torch.Size([2]), 3)
        >>> make_env("Pendulum-v1")
        Traceback (most recent call last):
        ...
        ValueError: Pendulum-v1 has a Box action space; model-based exploration plans over a discrete action set. Supported: mountaincar (MountainCar-v0), lunarlander (LunarLander-v3), acrobot (Acrobot-v1), cartpole (CartPole-v1).
    """
    env = TransformedEnv(
        GymEnv(resolve_env_id(name), device=device),
        Compose(DoubleToFloat(), StepCounter(), InitTracker(), RewardSum()),
    )
    if seed is not None:
        env.set_seed(seed)
    return env
