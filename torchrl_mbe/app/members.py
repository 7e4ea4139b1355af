"""Members leaving a population's batch: a part's saved state cut down to the members that stay.

A population's parts hold their members side by side along a member dimension
(docs/architecture.md, "Where the member dimension lives"): dimension 0 of the
parameters, their Adam moments and statistics, dimension 1 of what has the env
batch's shape ``(num_envs, M)`` (envs, the collector's carrier, novelty windows)
and of the replay storage ``(capacity, M)``. When members stop, the loop builds
its parts again for the members that stay and loads each part's state cut by
:func:`select_members`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch

__all__ = ["select_members"]


def select_members(state, index: Sequence[int], num_members: int, *, like=None, dim: int = 0):
    """``state`` (nested dicts, lists and tensors of ``num_members`` members) with only the members ``index``, in that order.

    A tensor whose counterpart in ``like`` (the state of the part built for
    ``len(index)`` members) has another shape is cut along the one dimension where
    the two differ; one of the same shape is kept whole. Where ``like`` has no
    counterpart, a tensor is cut along ``dim`` if that dimension holds the members
    (``num_members`` of them, or ``num_members`` blocks, as an ensemble's heads
    stacked member by member), and a list of ``num_members`` values keeps the
    values of ``index``. Anything else is kept as it is.

    Examples:
        >>> import torch
        >>> from torchrl_mbe.app.members import select_members
        >>> state = {"weight": torch.arange(6.0).view(3, 2), "losses": [0.1, 0.2, 0.3], "steps": 7}
        >>> select_members(state, [0, 2], num_members=3)
        {'weight': tensor([[0., 1.],
                [4., 5.]]), 'losses': [0.1, 0.3], 'steps': 7}
        >>> window = torch.arange(12.0).view(2, 3, 2)  # (num_envs, M, features)
        >>> select_members(window, [1], num_members=3, like=torch.zeros(2, 1, 2))[..., 0]
        tensor([[2.],
                [8.]])
    """
    if isinstance(state, Mapping):
        return {
            key: select_members(value, index, num_members, like=_entry(like, key), dim=dim)
            for key, value in state.items()
        }
    if isinstance(state, torch.Tensor):
        return _select_tensor(state, index, num_members, like, dim)
    if isinstance(state, (list, tuple)) and len(state) == num_members and like is None:
        return type(state)(state[member] for member in index)
    return state


def _entry(like, key):
    return like.get(key) if isinstance(like, Mapping) else None


def _select_tensor(tensor: torch.Tensor, index: Sequence[int], num_members: int, like, dim: int) -> torch.Tensor:
    """A copy, never the tensor itself: a new part must not share state with the one it replaces (Adam steps its counts in place)."""
    if isinstance(like, torch.Tensor):
        differing = [d for d, (old, new) in enumerate(zip(tensor.shape, like.shape, strict=True)) if old != new]
        if not differing:
            return tensor.clone()
        if len(differing) > 1:
            raise ValueError(f"a member's state of shape {tuple(tensor.shape)} cannot become {tuple(like.shape)}.")
        dim = differing[0]
    elif tensor.ndim <= dim or tensor.shape[dim] % num_members:
        return tensor.clone()
    blocks = tensor.unflatten(dim, (num_members, -1))  # a member's heads side by side
    chosen = torch.as_tensor(list(index), device=tensor.device)
    return blocks.index_select(dim, chosen).flatten(dim, dim + 1)
