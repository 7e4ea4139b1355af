"""The rolling window every novelty scorer keeps: its storage, the update and score contract, one window per batch element."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

__all__ = ["RollingWindowNovelty"]


class RollingWindowNovelty(nn.Module):
    """Base class: a circular buffer of the last ``window`` visited states.

    Subclasses implement :meth:`score`. One that fits something to the window
    (a mean, a factorized covariance) overrides :meth:`_refit` and calls
    :meth:`_refit_if_stale` before reading the fit: :meth:`update` and
    :meth:`reset` only write the window and mark the fit stale, so the fit runs
    once per window change, at the first score after it, and steps that update
    the window without scoring (greedy steps of an epsilon-greedy policy) cost
    no fit. The window, its write counter, the ``fit_stale`` flag and anything
    ``_refit`` caches are buffers: they travel together with ``state_dict``,
    ``.to(device)`` and collector weight sync. Compiled code cannot branch on
    ``fit_stale``: there the fit runs at every score.

    A scorer that fits running moments (:class:`DiagonalGaussianDensity`) also
    takes ``window=None``: every state it is given counts, none is kept.

    Args:
        num_features (int, optional): size of a state vector; inferred from the
            first :meth:`update` when ``None`` (the default).
        window (int or None): how many recent states to keep (the paper's F). At
            least 2; ``None`` only where ``counts_every_state`` is allowed.

    Keyword Args:
        batch_shape (tuple of int): one independent window per batch element.
            Defaults to ``()`` (one shared window).
        device (torch.device, optional): where the buffers live.
    """

    counts_every_state: bool = False  # whether window=None (every state given, none kept) is allowed

    def __init__(
        self,
        num_features: int | None = None,
        window: int | None = 50,
        *,
        batch_shape: Sequence[int] = (),
        device: torch.device | str | None = None,
    ) -> None:
        super().__init__()
        if num_features is not None and int(num_features) < 1:
            raise ValueError(f"num_features must be a positive integer or None, got {num_features}.")
        if window is None and not self.counts_every_state:
            raise ValueError(
                f"window=None: {type(self).__name__} scores against stored states; give it an integer >= 2."
            )
        if window is not None and int(window) < 2:
            raise ValueError(
                f"window must be an integer >= 2 (the paper uses 50), got {window}: "
                "a density needs at least two states to estimate a spread."
            )
        self.num_features: int | None = None
        self.window = None if window is None else int(window)
        self.batch_shape = torch.Size(batch_shape)
        self.register_buffer("states", None)
        self.register_buffer("num_seen", torch.zeros((), dtype=torch.int64, device=device))
        self.register_buffer("fit_stale", torch.ones((), dtype=torch.bool, device=device))
        if num_features is not None:
            self._allocate(int(num_features))

    def _allocate(self, num_features: int) -> None:
        """Creates the window (and, in subclasses, what the fit caches) for states of ``num_features``."""
        self.num_features = num_features
        if self.window is not None:
            self.states = torch.zeros(*self.batch_shape, self.window, num_features, device=self.num_seen.device)

    @property
    def num_stored(self) -> int:
        """How many states the fit counts: slots of the window holding one (at most ``window``), or every one seen."""
        return int(self.num_seen) if self.window is None else min(int(self.num_seen), self.window)

    def window_states(self) -> torch.Tensor:
        """The stored states in visiting order, shape ``(*batch_shape, num_stored, num_features)``."""
        if self.window is None:
            raise ValueError(f"{type(self).__name__}(window=None) keeps no states, only their moments.")
        seen, stored = int(self.num_seen), self.num_stored
        order = torch.arange(seen - stored, seen, device=self.states.device) % self.window
        return self.states[..., order, :]

    def _scored_window(self) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The states to score against, and which of them count (``None``: all).

        Eagerly, :meth:`window_states`. Compiled, every slot of the window and the
        mask of those that hold a state (slots fill from the first one up).
        """
        if not torch.compiler.is_compiling():
            return self.window_states(), None
        return self.states, torch.arange(self.window, device=self.num_seen.device) < self.num_seen

    def _empty_eagerly(self) -> bool:
        """Whether the window is empty, answered only eagerly: compiled scorers compute, then :meth:`_zeros_while_empty`."""
        return not torch.compiler.is_compiling() and self.num_stored == 0

    def _zeros_while_empty(self, scores: torch.Tensor) -> torch.Tensor:
        """``scores``, or zeros while the window is empty (a no-op eagerly, where scorers return zeros early)."""
        if not torch.compiler.is_compiling():
            return scores
        return torch.where(self.num_seen > 0, scores, torch.zeros_like(scores))

    @torch.no_grad()
    def update(self, states: torch.Tensor) -> None:
        """Pushes visited states, oldest first, into the window.

        Args:
            states (Tensor): shape ``(*sample_shape, *batch_shape, num_features)``;
                the sample dimensions are flattened in row-major (time) order.
                The first update sets ``num_features`` if the constructor did not.
        """
        if self.num_features is None:
            self._allocate(states.shape[-1])
        states = self._check_shape(states).reshape(-1, *self.batch_shape, self.num_features)
        if self.window is not None:
            states = states[-self.window :]
        self._before_push(states)
        if self.window is not None:
            self.states[..., self._next_slots(states.shape[0]), :] = states.movedim(0, -2).to(self.states)
        self.num_seen.add_(states.shape[0])
        self.fit_stale.fill_(True)

    def _before_push(self, states: torch.Tensor) -> None:
        """Sees the states :meth:`update` is about to push, ``(count, *batch_shape, num_features)``, before they overwrite any slot."""

    def _next_slots(self, count: int) -> torch.Tensor:
        """The window slots the next ``count`` (at most ``window``) states are written to."""
        return (self.num_seen + torch.arange(count, device=self.num_seen.device)) % self.window

    def reset(self) -> None:
        """Empties the window."""
        self.num_seen.zero_()
        self.fit_stale.fill_(True)

    def score(self, states: torch.Tensor) -> torch.Tensor:
        """Novelty of each state, shape ``states.shape[:-1]``; higher = rarer."""
        raise NotImplementedError

    def cell_scores(self) -> torch.Tensor:
        """The score of each one-hot state (state ``i``: the ``i``-th unit vector), ``(*batch_shape, num_features)``."""
        size, batch = self.num_features, self.batch_shape
        cells = torch.eye(size, device=self.num_seen.device).view(size, *[1] * len(batch), size)
        return self.score(cells.expand(size, *batch, size)).movedim(0, -1)

    def _refit_if_stale(self) -> None:
        """Runs :meth:`_refit` if the window changed since the last fit (always, when compiled)."""
        if torch.compiler.is_compiling() or self.fit_stale:
            self._refit()
            self.fit_stale.fill_(False)

    def _refit(self) -> None:
        """Recomputes what :meth:`score` reuses from the window (nothing here); see :meth:`_refit_if_stale`."""

    def _check_shape(self, states: torch.Tensor) -> torch.Tensor:
        trailing = (*self.batch_shape, self.num_features)
        if tuple(states.shape[states.ndim - len(trailing) :]) != trailing or states.ndim < len(trailing):
            raise ValueError(
                f"{type(self).__name__} expects states of shape (*sample_shape, "
                f"{', '.join(map(str, trailing))}), got {tuple(states.shape)}."
            )
        return states

    def _load_from_state_dict(self, state_dict: dict, prefix: str, *args, **kwargs) -> None:
        if self.num_features is None and prefix + "states" in state_dict:  # a window that never saw a state
            self._allocate(state_dict[prefix + "states"].shape[-1])
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def extra_repr(self) -> str:
        return f"num_features={self.num_features}, window={self.window}, batch_shape={tuple(self.batch_shape)}"
