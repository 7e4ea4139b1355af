"""Discrete action specs: what the planner, the dynamics model and the oracle read from one."""

from __future__ import annotations

import torch
from tensordict import NestedKey
from torch import nn
from torchrl.data import Categorical, Composite, OneHot, TensorSpec

__all__ = ["action_indices", "discrete_action_spec", "num_discrete_actions", "one_hot_actions"]


def discrete_action_spec(spec: TensorSpec, action_key: NestedKey = "action") -> OneHot | Categorical:
    """The ``OneHot`` or ``Categorical`` action spec that ``spec`` is or holds; a clear error otherwise.

    A ``Composite`` is read as :class:`~torchrl.modules.EGreedyModule` reads it,
    through its ``action_key`` entry: a :class:`~torchrl.modules.QValueActor`'s
    ``spec`` (``Composite(action=...)``) and an env's ``full_action_spec`` both do.

    Examples:
        >>> from torchrl.data import Composite, OneHot
        >>> from torchrl_mbe.modules.actions import discrete_action_spec
        >>> discrete_action_spec(Composite(action=OneHot(3))).space.n  # a QValueActor's spec
        3
        >>> discrete_action_spec(Composite(observation=OneHot(3)))
        Traceback (most recent call last):
        ...
        ValueError: Expected a Composite spec with an entry 'action', got one with keys ['observation'].
    """
    if isinstance(spec, Composite):
        if action_key not in spec.keys(include_nested=True):
            raise ValueError(
                f"Expected a Composite spec with an entry {action_key!r}, got one with keys {list(spec.keys(True, True))}."
            )
        spec = spec[action_key]
    if not isinstance(spec, (OneHot, Categorical)):
        raise TypeError(
            f"Model-based exploration needs a discrete action spec (OneHot or Categorical), got {type(spec).__name__}."
        )
    return spec


def num_discrete_actions(action_spec: TensorSpec) -> int:
    """Number of actions of a ``OneHot`` or ``Categorical`` spec (or of a ``Composite``'s ``"action"`` entry)."""
    return int(discrete_action_spec(action_spec).space.n)


def action_indices(action: torch.Tensor, action_spec: TensorSpec) -> torch.Tensor:
    """Integer action indices of actions encoded as ``action_spec`` encodes them."""
    return action.long().argmax(-1) if isinstance(action_spec, OneHot) else action.long()


def one_hot_actions(action: torch.Tensor, action_spec: TensorSpec) -> torch.Tensor:
    """Float one-hot encoding of actions encoded as ``action_spec`` encodes them."""
    if isinstance(action_spec, OneHot):
        return action.float()
    return nn.functional.one_hot(action.long(), num_discrete_actions(action_spec)).float()
