"""Visit counts: the count bonus ``1 / sqrt(n + 1)`` of a state's bucket, exact on one-hot states, SimHash on any other."""

from __future__ import annotations

from collections.abc import Sequence

import torch

from torchrl_mbe.modules.novelty.window import RollingWindowNovelty

__all__ = ["VisitCounts"]


class VisitCounts(RollingWindowNovelty):
    """The count bonus of a state: ``score(s) = 1 / sqrt(n(s) + 1)``, ``n(s)`` the visits to its bucket.

    The score is in ``(0, 1]`` whatever the task (1 for a state never visited), so it
    serves as an intrinsic reward as it is (Strehl & Littman's MBIE-EB bonus; Tang et
    al.'s "#Exploration" for hashed states) as well as a planner's score.

    * ``bits=None``: each entry of the state is a bucket, counted by its value. On
      one-hot states (DeepSea's cells, a ``Discrete`` observation) that is the exact
      visit count of each state, read by its hot index; a predicted state that is a
      probability vector (a categorical dynamics model's) scores the expected bonus, and
      a state of zeros (DeepSea's end of an episode) scores 0.
    * ``bits=k``: SimHash (Charikar 2002; Tang et al. 2017): the signs of ``k`` fixed
      random projections of the state are its bucket, one of ``2 ** k``; states in
      nearly the same direction share a bucket. The projections are the same for
      every scorer of a state size (drawn from a generator seeded 0).

    With ``window=None`` (the default) every visit counts; with an integer, the last
    ``window`` visits (an episodic count with ``window`` at least an episode's length).

    Args:
        num_features (int, optional): size of a state vector; inferred from the first update if ``None``.
        window (int, optional): how many recent visits count; ``None`` for all. Defaults to ``None``.

    Keyword Args:
        bits (int, optional): SimHash's code length; ``None`` to count each entry. Defaults to ``None``.
        batch_shape (tuple of int): one count table per batch element. Defaults to ``()``.
        device (torch.device, optional): where the buffers live.

    Examples:
        >>> import torch
        >>> from torchrl_mbe.modules import VisitCounts
        >>> cells = torch.eye(4)
        >>> counts = VisitCounts(4)
        >>> counts.update(cells[[0, 0, 0, 1]])  # cell 0 visited three times, cell 1 once
        >>> counts.score(cells)
        tensor([0.5000, 0.7071, 1.0000, 1.0000])
        >>> hashed = VisitCounts(2, bits=8)  # continuous states: SimHash buckets
        >>> hashed.update(torch.tensor([[1.0, 2.0]]).expand(3, 2))
        >>> hashed.score(torch.tensor([[1.0, 2.0]])).item()
        0.5
    """

    counts_every_state = True

    def __init__(
        self,
        num_features: int | None = None,
        window: int | None = None,
        *,
        bits: int | None = None,
        batch_shape: Sequence[int] = (),
        device: torch.device | str | None = None,
    ) -> None:
        if bits is not None and not 1 <= int(bits) <= 24:
            raise ValueError(f"bits must be an integer from 1 to 24 (2 ** bits buckets) or None, got {bits}.")
        self.bits = None if bits is None else int(bits)
        super().__init__(num_features, window, batch_shape=batch_shape, device=device)

    def extra_repr(self) -> str:
        return f"{super().extra_repr()}, bits={self.bits}"

    def _allocate(self, num_features: int) -> None:
        super()._allocate(num_features)
        device = self.num_seen.device
        num_buckets = num_features if self.bits is None else 2**self.bits
        self.register_buffer("counts", torch.zeros(*self.batch_shape, num_buckets, device=device))
        if self.bits is not None:  # a generator of its own: every scorer hashes alike, and torch's stream is untouched
            projection = torch.randn(num_features, self.bits, generator=torch.Generator().manual_seed(0))
            self.register_buffer("projection", projection.to(device))
            self.register_buffer("powers", 2 ** torch.arange(self.bits, device=device), persistent=False)

    def code(self, states: torch.Tensor) -> torch.Tensor:
        """Each state's SimHash bucket, ``states.shape[:-1]`` (``bits`` set)."""
        return ((states.to(self.projection) @ self.projection > 0).long() * self.powers).sum(-1)

    def _before_push(self, states: torch.Tensor) -> None:
        """Counts the entering states (``(count, *batch_shape, num_features)``) and uncounts the ones they overwrite in the window."""
        if self.window is not None:
            positions = self.num_seen + torch.arange(states.shape[0], device=self.num_seen.device)
            held = (positions >= self.window).to(self.counts.dtype)  # the slot holds an older state
            leaving = self.states[..., self._next_slots(states.shape[0]), :].movedim(-2, 0)
            self._add(leaving, -held.view(-1, *[1] * len(self.batch_shape)).expand(leaving.shape[:-1]))
        self._add(states, torch.ones(states.shape[:-1], device=self.counts.device))

    def _add(self, states: torch.Tensor, weights: torch.Tensor) -> None:
        """Adds ``weights`` (``(count, *batch_shape)``) visits of ``states`` to the counts."""
        if self.bits is None:
            self.counts.add_((states.to(self.counts) * weights.unsqueeze(-1)).sum(0))
        else:
            self.counts.scatter_add_(-1, self.code(states).movedim(0, -1), weights.movedim(0, -1).to(self.counts))

    def reset(self) -> None:
        super().reset()
        if self.num_features is not None:
            self.counts.zero_()

    def score(self, states: torch.Tensor) -> torch.Tensor:
        """``1 / sqrt(n + 1)`` of each state's bucket, ``n`` its visits; 1 before any visit.

        Without ``bits``, each entry's bonus weighted by the state read as a distribution
        over the entries: a one-hot state's own bonus, a probability vector's expected bonus
        (a prediction spread over cells never visited scores as high as one of them). Any
        other prediction (a randomized prior's offset added) weighs its positive entries,
        scaled to sum to at most 1.
        """
        if self.num_features is None:
            return states.new_ones(states.shape[:-1])
        states = self._check_shape(states)
        if self.bits is None:
            weights = states.to(self.counts).clamp(min=0)
            weights = weights / weights.sum(-1, keepdim=True).clamp(min=1)
            return (weights * (self.counts + 1).rsqrt()).sum(-1).to(states.dtype)
        code = self.code(states)
        visits = self.counts.expand(*code.shape, self.counts.shape[-1]).gather(-1, code.unsqueeze(-1)).squeeze(-1)
        return (visits + 1).rsqrt().to(states.dtype)

    def cell_scores(self) -> torch.Tensor:
        """Each one-hot state's bonus, ``(*batch_shape, num_features)``: read from the counts without ``bits``."""
        if self.bits is None and self.num_features is not None:
            return (self.counts + 1).rsqrt()
        return super().cell_scores()

    def _load_from_state_dict(self, state_dict: dict, prefix: str, *args, **kwargs) -> None:
        if self.num_features is None and prefix + "counts" in state_dict:  # window=None keeps no states to size from
            num_features = (
                state_dict[prefix + "counts"].shape[-1]
                if self.bits is None
                else state_dict[prefix + "projection"].shape[0]
            )
            self._allocate(num_features)
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)
