"""What a flat observation's spec says: its size, and the one-hot groups a one-hot observation is made of."""

from __future__ import annotations

from tensordict import NestedKey
from torchrl.data import Composite, MultiOneHot, OneHot, TensorSpec

__all__ = ["categorical_groups", "flat_observation_size", "hot_entries", "observation_entry"]


def hot_entries(observation_spec: TensorSpec) -> int | None:
    """How many ones a one-hot observation (``OneHot``, ``MultiOneHot``) holds: one per variable; ``None`` for any other.

    Examples:
        >>> from torchrl.data import MultiOneHot, OneHot, Unbounded
        >>> from torchrl_mbe.modules.observations import hot_entries
        >>> hot_entries(OneHot(9)), hot_entries(MultiOneHot([4, 3])), hot_entries(Unbounded(2))
        (1, 2, None)
    """
    if not isinstance(observation_spec, (OneHot, MultiOneHot)):
        return None
    return len(categorical_groups(observation_spec))


def categorical_groups(observation: int | TensorSpec, observation_key: NestedKey = "observation") -> tuple[int, ...]:
    """The sizes of the one-hot groups a flat observation is made of: a ``MultiOneHot`` spec's ``nvec``, else one group of every entry.

    A ``OneHot`` observation (DeepSea's cells, a gymnasium ``Discrete``) is one group; a
    ``MultiOneHot`` one (a ``MultiDiscrete``, a ``Tuple`` of ``Discrete``) one group per
    variable.

    Examples:
        >>> from torchrl.data import MultiOneHot, OneHot
        >>> from torchrl_mbe.modules.observations import categorical_groups
        >>> categorical_groups(MultiOneHot([4, 11, 6, 3])), categorical_groups(OneHot(9)), categorical_groups(9)
        ((4, 11, 6, 3), (9,), (9,))
    """
    observation = observation_entry(observation, observation_key)
    if isinstance(observation, MultiOneHot):
        return tuple(int(size) for size in observation.nvec)
    return (flat_observation_size(observation),)


def observation_entry(observation: int | TensorSpec, observation_key: NestedKey) -> int | TensorSpec:
    """``observation`` itself, or a ``Composite``'s (an env's ``observation_spec``) ``observation_key`` entry."""
    if isinstance(observation, Composite):
        if observation_key not in observation.keys(include_nested=True):
            raise ValueError(
                f"Expected the observation size or a spec with an entry {observation_key!r} "
                f"(e.g. env.observation_spec), got a Composite with keys {list(observation.keys(True, True))}."
            )
        return observation[observation_key]
    return observation


def flat_observation_size(observation: int | TensorSpec, observation_key: NestedKey = "observation") -> int:
    """The size of a flat observation: ``observation`` itself, or the last dimension of its spec (a ``Composite``'s ``observation_key`` entry)."""
    observation = observation_entry(observation, observation_key)
    if isinstance(observation, TensorSpec):
        if not observation.shape:
            raise ValueError(
                f"Expected a flat observation spec with a feature dimension, got shape {tuple(observation.shape)}."
            )
        return int(observation.shape[-1])
    return int(observation)
