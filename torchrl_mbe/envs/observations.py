"""Any gymnasium task as a DQN reads it: its observation as one float vector, its third-party suite imported.

TorchRL's ``GymWrapper`` reads a ``Box`` and a ``Discrete`` observation (one-hot) itself.
An observation made only of categorical variables (``MultiDiscrete``, ``MultiBinary``,
``Tuple`` or ``Dict`` of these with ``Discrete``: Blackjack's three numbers) becomes one
``MultiDiscrete``, which :func:`wrap_gymnasium` reads as a ``MultiOneHot`` spec: one
one-hot group per variable, which tells a model which entries belong together
(:func:`~torchrl_mbe.modules.dynamics.categorical_groups`). Any other space (a
``Tuple`` or ``Dict`` holding a ``Box``, a ``Box`` of integers such as MiniGrid's 7x7x3
object, colour and state codes, kept as the codes: docs/results.md, section 7) is
flattened by gymnasium's own ``FlattenObservation`` into float32, which TorchRL 0.14's
``GymWrapper`` cannot do for a ``Tuple`` of unequal ``Discrete`` spaces (Blackjack)
nor for MiniGrid's ``MissionSpace``. Entries that cannot be flattened (a mission
text) are dropped, with one log line. Everything else is refused, in
one line, before any work: a non-discrete action space, variable-size spaces
(``Text``, ``Sequence``, ``Graph``) and observations of more than
:data:`MAX_OBSERVATION_SIZE` numbers (pixels: the models here are MLPs on flat
vectors, and a full-covariance window over ``d`` numbers costs ``d**2`` memory).
"""

from __future__ import annotations

import functools
import importlib
import logging
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces
from gymnasium.wrappers import DtypeObservation, FilterObservation, FlattenObservation, TransformObservation
from torchrl.data import MultiOneHot
from torchrl.envs import GymWrapper

__all__ = [
    "MAX_EPISODE_STEPS",
    "MAX_OBSERVATION_SIZE",
    "SUITES",
    "check_gymnasium",
    "import_suite",
    "make_gymnasium",
    "wrap_gymnasium",
]

log = logging.getLogger(__name__)

MAX_OBSERVATION_SIZE = 4096
"""The most numbers a flat observation may have (DeepSea-64's grid; a 36x36 RGB image)."""

MAX_EPISODE_STEPS = 1000
"""The time limit of a task that has none (CliffWalking's, where a greedy policy can walk in circles forever)."""

SUITES = {"MiniGrid-": "minigrid", "BabyAI-": "minigrid"}
"""Third-party suites whose ids exist once their package is imported: id prefix -> package."""


def import_suite(name: str) -> str:
    """Imports the package that registers ``name`` (gymnasium's ``module:EnvId`` spelling, or a :data:`SUITES` prefix); returns the bare id.

    Examples:
        >>> from torchrl_mbe.envs.observations import import_suite
        >>> import_suite("gymnasium.envs.toy_text:FrozenLake-v1"), import_suite("CartPole-v1")
        ('FrozenLake-v1', 'CartPole-v1')
    """
    module, _, env_id = name.rpartition(":")
    module = module or next((package for prefix, package in SUITES.items() if env_id.startswith(prefix)), "")
    if module:
        try:
            importlib.import_module(module)
        except ImportError:
            extra = f"pip install -e '.[{module}]'" if module in SUITES.values() else f"pip install {module}"
            raise ValueError(f"{name} needs the package {module!r}, which is not installed ({extra}).") from None
    return env_id


def check_gymnasium(env_id: str, **make_kwargs: Any) -> None:
    """Builds and resets ``env_id`` once as :func:`make_gymnasium` does: raises its ``ValueError``, or one for a package its first reset lacks."""
    env = make_gymnasium(env_id, **make_kwargs)
    try:
        env.reset(seed=0)
    except gym.error.DependencyNotInstalled as error:
        raise ValueError(f"{env_id} needs a package that is not installed: {error}") from None
    finally:
        env.close()


def make_gymnasium(env_id: str, **make_kwargs: Any) -> gym.Env:
    """``gym.make(env_id, **make_kwargs)`` with its observation as :class:`~torchrl.envs.GymWrapper` reads it for DQN.

    A ``Box`` of floats and a ``Discrete`` pass as they are; an observation of
    categorical variables becomes one ``MultiDiscrete``; any other observation space
    is flattened to a float32 vector (``Dict`` entries that cannot be, such as a
    mission text, dropped first). A task without a time limit gets
    :data:`MAX_EPISODE_STEPS`.

    Raises:
        ValueError: naming the space and what is accepted, for a task a DQN here
            cannot act in or read (see the module's docstring).

    Examples:
        >>> from torchrl_mbe.envs.observations import make_gymnasium
        >>> make_gymnasium("Blackjack-v1").observation_space  # three categorical variables
        MultiDiscrete([32 11  2])
        >>> make_gymnasium("FrozenLake-v1", is_slippery=False).observation_space
        Discrete(16)
        >>> make_gymnasium("Pendulum-v1")
        Traceback (most recent call last):
        ...
        ValueError: Pendulum-v1 has a Box(-2.0, 2.0, (1,), float32) action space; model-based exploration plans over one discrete action set (a Discrete action space).
    """
    time_limit = {"max_episode_steps": MAX_EPISODE_STEPS} if gym.spec(env_id).max_episode_steps is None else {}
    try:
        env = gym.make(env_id, **{**time_limit, **make_kwargs})  # the caller's max_episode_steps wins
    except TypeError as error:
        raise ValueError(f"{env_id} does not take the keyword arguments {make_kwargs} (gym.make: {error}).") from None
    except gym.error.DependencyNotInstalled as error:
        raise ValueError(f"{env_id} needs a package that is not installed: {error}") from None
    try:
        return _flat_observation(env_id, env)
    except ValueError:
        env.close()
        raise


def wrap_gymnasium(env: gym.Env, device: torch.device | str | None = None) -> GymWrapper:
    """TorchRL's ``GymWrapper`` of a :func:`make_gymnasium` env, its ``MultiDiscrete`` observation read as one ``MultiOneHot`` vector.

    TorchRL reads a ``MultiDiscrete`` of unequal sizes so, and one of equal sizes
    (``MultiBinary``'s bits, ``MultiDiscrete([3, 3])``) as a stack of ``OneHot`` rows.

    Examples:
        >>> from torchrl_mbe.envs.observations import make_gymnasium, wrap_gymnasium
        >>> wrap_gymnasium(make_gymnasium("Blackjack-v1")).observation_spec["observation"].nvec
        [32, 11, 2]
    """
    wrapper = GymWrapper(env, device=device)
    space = env.observation_space
    if isinstance(space, spaces.MultiDiscrete) and len(space.shape) == 1:
        observation_spec = wrapper.observation_spec.clone().unlock_()
        observation_spec["observation"] = MultiOneHot(
            [int(size) for size in space.nvec], device=wrapper.device, dtype=torch.long
        )
        wrapper.observation_spec = observation_spec
    return wrapper


@functools.cache
def _log_dropped(env_id: str, dropped: tuple[str, ...]) -> None:
    """Says once per process which entries of a task's observation are dropped (every env copy drops the same)."""
    log.info("%s: the observation entries %s are dropped (not a fixed number of numbers)", env_id, list(dropped))


def _flat_observation(env_id: str, env: gym.Env) -> gym.Env:
    if not isinstance(env.action_space, spaces.Discrete):
        raise ValueError(
            f"{env_id} has a {env.action_space} action space; model-based exploration plans over one discrete action set (a Discrete action space)."
        )
    space = env.observation_space
    if isinstance(space, spaces.Dict):
        kept = [key for key, entry in space.spaces.items() if _flattenable(entry)]
        if kept and len(kept) < len(space.spaces):
            _log_dropped(env_id, tuple(sorted(set(space.spaces) - set(kept))))
            env = FilterObservation(env, kept)
            space = env.observation_space
    if not _flattenable(space) or not spaces.flatdim(space):
        raise ValueError(
            f"{env_id} has a {space} observation; accepted: Box, Discrete, MultiDiscrete, MultiBinary, and Tuple or Dict of these."
        )
    if spaces.flatdim(space) > MAX_OBSERVATION_SIZE:
        raise ValueError(
            f"{env_id} has an observation of {spaces.flatdim(space)} numbers; at most {MAX_OBSERVATION_SIZE} are accepted (the models are "
            "MLPs on flat vectors: for pixels, use a smaller or symbolic observation, such as MiniGrid's default 7x7x3 codes)."
        )
    if isinstance(space, spaces.Discrete) or (
        isinstance(space, spaces.Box) and np.issubdtype(space.dtype, np.floating) and len(space.shape) == 1
    ):
        return env  # GymWrapper reads these as they are (a Discrete one-hot)
    if _categorical(space):
        return TransformObservation(
            env, lambda observation: _category_indices(space, observation), _multi_discrete(space)
        )
    return DtypeObservation(FlattenObservation(env), np.float32)


def _categorical(space: spaces.Space) -> bool:
    """Whether ``space`` holds only categorical variables (``Discrete``, ``MultiDiscrete``, ``MultiBinary``, and ``Tuple`` or ``Dict`` of these)."""
    if isinstance(space, (spaces.Tuple, spaces.Dict)):
        return all(map(_categorical, _entries(space)))
    return isinstance(space, (spaces.Discrete, spaces.MultiDiscrete, spaces.MultiBinary))


def _multi_discrete(space: spaces.Space) -> spaces.MultiDiscrete:
    """The one ``MultiDiscrete`` of a categorical ``space``'s variables, in gymnasium's flattening order."""
    return spaces.MultiDiscrete(np.concatenate(_category_counts(space)))


def _category_counts(space: spaces.Space) -> list[np.ndarray]:
    if isinstance(space, spaces.Discrete):
        return [np.array([space.n])]
    if isinstance(space, spaces.MultiDiscrete):
        return [np.asarray(space.nvec).ravel()]
    if isinstance(space, spaces.MultiBinary):
        return [np.full(int(np.prod(space.shape)), 2)]
    return [counts for entry in _entries(space) for counts in _category_counts(entry)]


def _category_indices(space: spaces.Space, observation: Any) -> np.ndarray:
    """A categorical ``space``'s observation as the indices its :func:`_multi_discrete` space holds."""
    if isinstance(space, spaces.Discrete):
        return np.array([observation - space.start], dtype=np.int64)
    if isinstance(space, spaces.MultiDiscrete):
        return (np.asarray(observation) - space.start).ravel().astype(np.int64)
    if isinstance(space, spaces.MultiBinary):
        return np.asarray(observation).ravel().astype(np.int64)
    if isinstance(space, spaces.Dict):
        return np.concatenate([_category_indices(entry, observation[key]) for key, entry in space.spaces.items()])
    return np.concatenate([_category_indices(entry, value) for entry, value in zip(space.spaces, observation)])


def _flattenable(space: spaces.Space) -> bool:
    """Whether ``space`` is a fixed number of numbers (a text, which gymnasium would flatten to character codes, or a sequence is not)."""
    if isinstance(space, spaces.Text):
        return False
    if isinstance(space, (spaces.Tuple, spaces.Dict)):
        return all(map(_flattenable, _entries(space)))
    try:
        return bool(space.is_np_flattenable)
    except NotImplementedError:  # MiniGrid's MissionSpace
        return False


def _entries(space: spaces.Tuple | spaces.Dict) -> list[spaces.Space]:
    """A ``Tuple``'s or ``Dict``'s spaces, in order (a ``Dict``'s in its keys' order)."""
    return list(space.spaces.values()) if isinstance(space, spaces.Dict) else list(space.spaces)
