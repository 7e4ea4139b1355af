"""Environments: the task registry, ``make_env``, the torch-batched tasks and the gymnasium batch.

The torch-batched envs are MountainCar-v0, CartPole-v1, Acrobot-v1 and bsuite's
DeepSea (MountainCar and DeepSea with their oracle dynamics); each one's ``state_dict`` holds its whole state,
random generator included (see :class:`~torchrl_mbe.envs.batched.BatchedTorchEnv`).
:class:`~torchrl_mbe.envs.gym_batch.GymBatchEnv` steps a batch of gymnasium envs
(LunarLander's, or any task with ``backend="gym"``).
"""

from __future__ import annotations

from torchrl_mbe.envs.acrobot import BatchedAcrobotEnv, acrobot_step
from torchrl_mbe.envs.cartpole import BatchedCartPoleEnv, cartpole_step
from torchrl_mbe.envs.deepsea import BatchedDeepSeaEnv, DeepSeaDynamics
from torchrl_mbe.envs.episodes import Episode, finished_episodes, first_episodes, play_first_episodes, reached_goal
from torchrl_mbe.envs.gym_batch import GymBatchEnv
from torchrl_mbe.envs.make import make_env
from torchrl_mbe.envs.mountaincar import BatchedMountainCarEnv, MountainCarDynamics, mountaincar_step
from torchrl_mbe.envs.registry import SUPPORTED_ENVS, TASKS, EnvBounds, Task, resolve_env_id, task_of

__all__ = [
    "SUPPORTED_ENVS",
    "TASKS",
    "BatchedAcrobotEnv",
    "BatchedCartPoleEnv",
    "BatchedDeepSeaEnv",
    "BatchedMountainCarEnv",
    "DeepSeaDynamics",
    "EnvBounds",
    "Episode",
    "GymBatchEnv",
    "MountainCarDynamics",
    "Task",
    "acrobot_step",
    "cartpole_step",
    "finished_episodes",
    "first_episodes",
    "make_env",
    "mountaincar_step",
    "play_first_episodes",
    "reached_goal",
    "resolve_env_id",
    "task_of",
]
