"""The task registry: every per-environment fact, in one place.

A :class:`Task` names an environment the project is tested on (a gymnasium id,
or for DeepSea, which exists only in torch, its own id) and says what the rest of
the code needs to know about it: its short name, when it counts as solved, what
reaching its goal means, the box its coverage is measured in and, if there is
one, its batched torch implementation. Adding an environment means
adding one entry to :data:`TASKS` (and a ``conf/env/<alias>.yaml`` for the app).
"""

from __future__ import annotations

import inspect
import math
from dataclasses import dataclass, replace
from typing import Any, Literal

import gymnasium as gym
import numpy as np
from tensordict.nn import TensorDictModuleBase
from torchrl.envs import EnvBase

from torchrl_mbe.envs.acrobot import BatchedAcrobotEnv
from torchrl_mbe.envs.cartpole import BatchedCartPoleEnv
from torchrl_mbe.envs.deepsea import BatchedDeepSeaEnv, DeepSeaDynamics
from torchrl_mbe.envs.mountaincar import BatchedMountainCarEnv, MountainCarDynamics
from torchrl_mbe.envs.observations import check_gymnasium, import_suite

__all__ = [
    "SUITE_TASKS",
    "SUPPORTED_ENVS",
    "TASKS",
    "EnvBounds",
    "SolvedRule",
    "Task",
    "resolve_env_id",
    "solved_rule",
    "task_of",
]

GoalRule = Literal["terminated", "truncated", "landed"]


@dataclass(frozen=True)
class SolvedRule:
    """When a greedy evaluation counts as solving its task: its ``metric`` (an evaluation result's key) at or above ``threshold``."""

    metric: Literal["eval_return_mean", "eval_success_rate"]
    threshold: float


@dataclass(frozen=True)
class EnvBounds:
    """The box coverage is measured in, and how to read an environment's state.

    Args:
        low (tuple of float): lower bound of every observation dimension.
        high (tuple of float): upper bound of every observation dimension.
        labels (tuple of str): a name for every observation dimension.
        plane (tuple of int): the two dimensions of the scatter plot and of the
            grid coverage (the paper's figures).
        continuous_dims (tuple of int): the dimensions pairwise coverage averages over.
        progress_dim (int, optional): a dimension whose maximum measures progress
            towards the goal (MountainCar's position), or ``None``.
    """

    low: tuple[float, ...]
    high: tuple[float, ...]
    labels: tuple[str, ...]
    plane: tuple[int, int] = (0, 1)
    continuous_dims: tuple[int, ...] | None = None
    progress_dim: int | None = None

    @property
    def plane_low(self) -> tuple[float, float]:
        """Lower bounds of the two plane dimensions."""
        return self.low[self.plane[0]], self.low[self.plane[1]]

    @property
    def plane_high(self) -> tuple[float, float]:
        """Upper bounds of the two plane dimensions."""
        return self.high[self.plane[0]], self.high[self.plane[1]]

    @property
    def coverage_dims(self) -> tuple[int, ...]:
        """The dimensions pairwise coverage uses: ``continuous_dims``, else all."""
        return tuple(range(len(self.low))) if self.continuous_dims is None else self.continuous_dims

    @classmethod
    def from_states(cls, states: np.ndarray) -> EnvBounds:
        """Bounds fitted to the visited states themselves, for an environment without an entry.

        Examples:
            >>> import numpy as np
            >>> from torchrl_mbe.envs.registry import EnvBounds
            >>> EnvBounds.from_states(np.array([[0.0, 1.0], [2.0, 3.0]])).high
            (2.0, 3.0)
        """
        states = np.asarray(states, dtype=np.float64).reshape(len(states), -1)
        labels = tuple(f"dim {i}" for i in range(states.shape[1]))
        return cls(tuple(states.min(0).tolist()), tuple(states.max(0).tolist()), labels)


@dataclass(frozen=True)
class Task:
    """What the project knows about one environment.

    Args:
        alias (str): the short name used by ``make_env`` and ``conf/env/``.
        env_id (str): the gymnasium id (with ``gymnasium=False``, the task's own id).
        solved_threshold (float): average return over 100 episodes at which
            gymnasium calls the task solved (with ``solved_by="success"``, the
            fraction of episodes that reach the goal).
        goal (str): what counts as reaching the goal in an episode:
            ``"terminated"`` (the env's own termination), ``"truncated"`` (lasting
            until the time limit) or ``"landed"`` (terminated with a positive last
            reward: LunarLander's landing, DeepSea's treasure).
        bounds (EnvBounds, optional): the box coverage is measured in; ``None`` when
            no fixed box fits (DeepSea's one-hot observation has ``size**2`` entries).
        torch_env (type, optional): a batched torch implementation
            (``cls(num_envs, device=..., **env_kwargs)``), used by ``make_env(..., backend="torch")``.
        gymnasium (bool): whether ``env_id`` is a gymnasium id; ``False`` for a
            task that exists only as ``torch_env``.
        oracle (type, optional): the task's exact dynamics as a dynamics module
            (``cls(action_spec, **env_kwargs)``, the ``env_kwargs`` of ``torch_env``),
            for ``dynamics=oracle``; ``None`` where the project has none.
        solved_by (str): ``"return"`` (the average return) or ``"success"`` (the
            fraction of episodes that reach the goal) is what ``solved_threshold`` bounds.
    """

    alias: str
    env_id: str
    solved_threshold: float
    goal: GoalRule
    bounds: EnvBounds | None
    torch_env: type[EnvBase] | None = None
    gymnasium: bool = True
    oracle: type[TensorDictModuleBase] | None = None
    solved_by: Literal["return", "success"] = "return"

    @property
    def options(self) -> tuple[str, ...]:
        """The keyword arguments a torch-only task takes (its ``torch_env``'s, beside ``num_envs``, ``seed``, ``device``); a gymnasium task's are ``gym.make``'s.

        Examples:
            >>> from torchrl_mbe.envs.registry import TASKS
            >>> TASKS["deepsea"].options[:2], TASKS["cartpole"].options
            (('size', 'mapping_seed'), ())
        """
        if self.gymnasium or self.torch_env is None:
            return ()
        parameters = inspect.signature(self.torch_env.__init__).parameters
        return tuple(name for name in parameters if name not in ("self", "num_envs", "seed", "device"))


TASKS: dict[str, Task] = {
    task.alias: task
    for task in (
        Task(
            "mountaincar",
            "MountainCar-v0",
            solved_threshold=-110.0,
            goal="terminated",  # the car reached the flag
            bounds=EnvBounds(low=(-1.2, -0.07), high=(0.6, 0.07), labels=("position", "velocity"), progress_dim=0),
            torch_env=BatchedMountainCarEnv,
            oracle=MountainCarDynamics,
        ),
        Task(
            "lunarlander",
            "LunarLander-v3",
            solved_threshold=200.0,
            goal="landed",  # terminated at rest (+100), not crashed (-100)
            # Fixed boxes from the observation definition and random-policy ranges; LunarLander's
            # own observation space (velocities +-10) is far looser than anything reachable.
            bounds=EnvBounds(
                low=(-1.0, -0.25, -2.0, -2.5, -math.pi, -5.0, 0.0, 0.0),
                high=(1.0, 1.75, 2.0, 1.0, math.pi, 5.0, 1.0, 1.0),
                labels=("x", "y", "x-velocity", "y-velocity", "angle", "angular velocity", "left leg", "right leg"),
                plane=(2, 3),
                continuous_dims=(0, 1, 2, 3, 4, 5),
            ),
        ),
        Task(
            "acrobot",
            "Acrobot-v1",
            solved_threshold=-100.0,
            goal="terminated",  # the tip swung above the line
            bounds=EnvBounds(
                low=(-1.0, -1.0, -1.0, -1.0, -4 * math.pi, -9 * math.pi),
                high=(1.0, 1.0, 1.0, 1.0, 4 * math.pi, 9 * math.pi),
                labels=("cos theta1", "sin theta1", "cos theta2", "sin theta2", "theta1 velocity", "theta2 velocity"),
                plane=(4, 5),
            ),
            torch_env=BatchedAcrobotEnv,
        ),
        Task(
            "cartpole",
            "CartPole-v1",
            solved_threshold=475.0,
            goal="truncated",  # balanced until the time limit
            bounds=EnvBounds(
                low=(-2.4, -3.0, -0.2095, -3.5),
                high=(2.4, 3.0, 0.2095, 3.5),
                labels=("cart position", "cart velocity", "pole angle", "pole angular velocity"),
                plane=(0, 2),
            ),
            torch_env=BatchedCartPoleEnv,
        ),
        Task(
            "deepsea",
            "DeepSea",
            # An episode returns 0.99 if it finds the treasure and at most 0 if not (the
            # deterministic default), so a greedy evaluation averages 0.99 or <= 0: 0.5 means
            # the greedy policy gets the treasure, and over 100 training episodes that more
            # than half of them did. Not meant for the stochastic variant (noisy rewards).
            solved_threshold=0.5,
            goal="landed",  # terminated with a positive last reward: the treasure, the only positive reward
            bounds=None,  # the report would decode the one-hot observation to a (row, column) plane
            torch_env=BatchedDeepSeaEnv,
            gymnasium=False,
            oracle=DeepSeaDynamics,
        ),
    )
}
"""The tested environments, by short name."""

SUITE_TASKS: dict[str, Task] = {
    prefix: Task(
        "minigrid",
        prefix,
        # MiniGrid's reward is 1 - 0.9 * steps / max_steps at the goal and 0 otherwise, and its
        # specs have no reward_threshold: solved is the goal reached in 90% of greedy episodes.
        solved_threshold=0.9,
        solved_by="success",
        goal="landed",  # terminated with a positive reward: the goal, not lava or a wrong door
        bounds=None,
    )
    for prefix in ("MiniGrid-", "BabyAI-")
}
"""The tasks of a third-party suite, by the prefix of their ids (each id gets the entry with its own ``env_id``)."""

SUPPORTED_ENVS: dict[str, str] = {alias: task.env_id for alias, task in TASKS.items()}
"""Short names accepted everywhere (config files, ``make_env``) and their ids (gymnasium's, or DeepSea's own)."""


def task_of(env_id: str) -> Task | None:
    """The registry entry of an env id (:data:`TASKS`, or its suite's in :data:`SUITE_TASKS`), or ``None`` for an untested environment.

    Examples:
        >>> from torchrl_mbe.envs.registry import task_of
        >>> task_of("CartPole-v1").solved_threshold
        475.0
        >>> task_of("MiniGrid-DoorKey-5x5-v0").solved_by
        'success'
    """
    task = next((task for task in TASKS.values() if task.env_id == env_id), None)
    prefix = next((prefix for prefix in SUITE_TASKS if env_id.startswith(prefix)), None)
    return replace(SUITE_TASKS[prefix], env_id=env_id) if task is None and prefix is not None else task


def solved_rule(env_id: str) -> SolvedRule | None:
    """When ``env_id`` counts as solved: its registry entry's rule, else gymnasium's ``reward_threshold``; ``None`` if neither says.

    Examples:
        >>> from torchrl_mbe.envs.registry import solved_rule
        >>> solved_rule("FrozenLake8x8-v1"), solved_rule("CliffWalking-v1")
        (SolvedRule(metric='eval_return_mean', threshold=0.85), None)
    """
    task = task_of(env_id)
    if task is not None:
        return SolvedRule(
            "eval_success_rate" if task.solved_by == "success" else "eval_return_mean", task.solved_threshold
        )
    threshold = gym.spec(env_id).reward_threshold
    return SolvedRule("eval_return_mean", float(threshold)) if threshold is not None else None


def _supported_list() -> str:
    return ", ".join(f"{alias} ({env_id})" for alias, env_id in SUPPORTED_ENVS.items())


def resolve_env_id(name: str, **make_kwargs: Any) -> str:
    """The env id of a short name or id; one clear error for anything unsupported.

    Any registered gymnasium id with a discrete action space and an observation
    :func:`~torchrl_mbe.envs.observations.make_gymnasium` reads is accepted (a
    third-party suite's too: gymnasium's ``module:EnvId`` spelling, or a
    :data:`~torchrl_mbe.envs.observations.SUITES` prefix such as ``MiniGrid-``),
    built and reset once with ``make_kwargs`` to check it; and the torch-only tasks of
    :data:`TASKS` (``gymnasium=False``). The project is tested on the entries of
    :data:`TASKS` and :data:`SUITE_TASKS`.

    Examples:
        >>> from torchrl_mbe.envs.registry import resolve_env_id
        >>> resolve_env_id("acrobot"), resolve_env_id("deepsea"), resolve_env_id("minigrid:MiniGrid-Empty-5x5-v0")
        ('Acrobot-v1', 'DeepSea', 'MiniGrid-Empty-5x5-v0')
        >>> resolve_env_id("CartPole-v1", length=1)  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        ValueError: CartPole-v1 does not take the keyword arguments {'length': 1} (gym.make: ...
    """
    env_id = import_suite(SUPPORTED_ENVS.get(name.lower(), name))
    task = task_of(env_id)
    if task is not None and not task.gymnasium:
        return env_id
    if env_id not in gym.registry:
        raise ValueError(
            f"Unknown environment {name!r}: expected a gymnasium id (module:EnvId for a third-party suite) or one of {_supported_list()}."
        )
    check_gymnasium(env_id, **make_kwargs)
    return env_id
