"""Kernel and neighbour scorers of the window: the paper's Gaussian kernel baseline, k nearest neighbours, a kernel density estimate."""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

from torchrl_mbe.modules.novelty.window import RollingWindowNovelty

__all__ = ["GaussianKernelNovelty", "KNearestNovelty", "KernelDensityNovelty"]


class GaussianKernelNovelty(RollingWindowNovelty):
    """Kernel-similarity novelty, the baseline the paper compares against (Oh et al., 2015).

    ``score(s) = -sum_i k(s, s_i)`` over the states ``s_i`` of the window, with the
    Gaussian kernel ``k(s, s') = exp(-||(s - s') / bandwidth||^2 / 2)``. Unlike
    :class:`RollingGaussianDensity` it measures plain (scaled) distances and
    ignores correlations between dimensions.

    Args:
        num_features (int, optional): size of a state vector; inferred from the first update if ``None``.
        window (int): number of recent states compared against. Defaults to 50.

    Keyword Args:
        bandwidth (float or sequence of float): kernel width, one per feature or
            shared. Defaults to ``0.1``.
        batch_shape (tuple of int): one window per batch element. Defaults to ``()``.
        device (torch.device, optional): where the buffers live.

    Examples:
        >>> import torch
        >>> from torchrl_mbe import GaussianKernelNovelty
        >>> novelty = GaussianKernelNovelty(window=10, bandwidth=0.5)  # the state size comes with the first update
        >>> novelty.update(torch.zeros(10, 2))
        >>> novelty.score(torch.tensor([[0.0, 0.0], [1.0, 0.0]]))
        tensor([-10.0000,  -1.3534])
    """

    def __init__(
        self,
        num_features: int | None = None,
        window: int = 50,
        *,
        bandwidth: float | Sequence[float] = 0.1,
        batch_shape: Sequence[int] = (),
        device: torch.device | str | None = None,
    ) -> None:
        super().__init__(None, window, batch_shape=batch_shape, device=device)
        bandwidth = torch.as_tensor(bandwidth, dtype=torch.float32, device=device)
        if (bandwidth <= 0).any() or bandwidth.ndim > 1:
            raise ValueError(f"bandwidth must be positive, one value or one per feature, got {bandwidth.tolist()}.")
        self.register_buffer("bandwidth", bandwidth)
        if num_features is not None:
            self._allocate(int(num_features))

    def _allocate(self, num_features: int) -> None:
        if self.bandwidth.numel() not in (1, num_features):
            raise ValueError(
                f"bandwidth must be positive, one value or {num_features} values, got {self.bandwidth.tolist()}."
            )
        super()._allocate(num_features)
        self.bandwidth = self.bandwidth.expand(num_features).clone()

    def score(self, states: torch.Tensor) -> torch.Tensor:
        """``-sum_i k(s, s_i)``: higher = rarer; zeros while the window is empty."""
        if self.num_features is None:
            return states.new_zeros(states.shape[:-1])
        states = self._check_shape(states)
        stored, filled = self._scored_window()
        scaled_distance = (states.unsqueeze(-2) - stored) / self.bandwidth
        kernels = torch.exp(-0.5 * scaled_distance.square().sum(-1))
        return -(kernels if filled is None else kernels * filled).sum(-1)


def _offsets_in_window_spreads(
    states: torch.Tensor, stored: torch.Tensor, filled: torch.Tensor | None, min_scale: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """``(s - s_i) / sigma`` for every state and stored state, ``(..., N, D)``, and ``sigma``.

    ``sigma`` is the window's spread in each dimension (over the ``filled`` slots
    only, unless ``None``), floored at ``min_scale``: the scale-free distances of
    :class:`KNearestNovelty` and :class:`KernelDensityNovelty`.
    """
    if filled is None:
        spread = stored.std(-2, correction=0, keepdim=True)
    else:
        weights, count = filled.to(stored).unsqueeze(-1), filled.sum().clamp_min(1)
        mean = (stored * weights).sum(-2, keepdim=True) / count
        spread = (((stored - mean) * weights).square().sum(-2, keepdim=True) / count).sqrt()
    spread = spread.clamp_min(min_scale)
    return (states.unsqueeze(-2) - stored) / spread, spread


class KNearestNovelty(RollingWindowNovelty):
    """Distance to the ``k`` nearest states of the window (a k-nearest-neighbour novelty).

    ``score(s)`` is the mean distance from ``s`` to its ``k`` nearest neighbours
    among the last ``window`` visited states, each dimension divided by its spread
    over the window (so, like the Gaussian and unlike the kernel with a fixed
    bandwidth, it is scale-free). Non-parametric: it sees several clusters where a
    Gaussian sees one blob.

    Args:
        num_features (int, optional): size of a state vector; inferred from the first update if ``None``.
        window (int): number of recent states compared against. Defaults to 50.

    Keyword Args:
        k (int): neighbours averaged (at most the states stored). Defaults to 5.
        batch_shape (tuple of int): one window per batch element. Defaults to ``()``.
        min_scale (float): floor on each dimension's spread. Defaults to ``1e-6``.
        device (torch.device, optional): where the buffers live.

    Examples:
        >>> import torch
        >>> from torchrl_mbe.modules import KNearestNovelty
        >>> novelty = KNearestNovelty(window=4, k=2)
        >>> novelty.update(torch.tensor([[0.0, 0.0], [0.0, 1.0], [1.0, 0.0], [1.0, 1.0]]))
        >>> scores = novelty.score(torch.tensor([[0.5, 0.5], [3.0, 3.0]]))
        >>> bool(scores[1] > scores[0])
        True
    """

    def __init__(
        self,
        num_features: int | None = None,
        window: int = 50,
        *,
        k: int = 5,
        batch_shape: Sequence[int] = (),
        min_scale: float = 1e-6,
        device: torch.device | str | None = None,
    ) -> None:
        super().__init__(num_features, window, batch_shape=batch_shape, device=device)
        if int(k) < 1:
            raise ValueError(f"k must be a positive integer, got {k}.")
        self.k = int(k)
        self.min_scale = float(min_scale)

    def score(self, states: torch.Tensor) -> torch.Tensor:
        """Mean scaled distance to the ``k`` nearest stored states: higher = rarer; zeros while the window is empty."""
        if self._empty_eagerly():
            return states.new_zeros(states.shape[:-1])
        stored, filled = self._scored_window()
        offsets, _ = _offsets_in_window_spreads(self._check_shape(states), stored, filled, self.min_scale)
        distances = offsets.norm(dim=-1)
        if filled is None:
            return distances.topk(min(self.k, self.num_stored), dim=-1, largest=False).values.mean(-1)
        nearest = distances.masked_fill(~filled, torch.inf).topk(min(self.k, self.window), dim=-1, largest=False).values
        counted = nearest.isfinite()  # min(k, num_stored) of them
        return self._zeros_while_empty(nearest.where(counted, 0.0).sum(-1) / counted.sum(-1).clamp_min(1))


class KernelDensityNovelty(RollingWindowNovelty):
    """Kernel density estimate over a long window of visited states.

    ``score(s) = -log (1/N) sum_i N(s | s_i, diag(h^2))`` over the ``N`` stored states,
    with Scott's rule for the bandwidth of each dimension,
    ``h_d = sigma_d N^(-1/(D+4))`` (``sigma_d``: the window's spread in that
    dimension). A proper density, like :class:`RollingGaussianDensity`, but
    non-parametric: several clusters of visited states (both sides of a valley)
    stay several modes instead of one wide blob. Its cost grows with the window
    (default 500), where the Gaussian's does not.

    Args:
        num_features (int, optional): size of a state vector; inferred from the first update if ``None``.
        window (int): number of recent states the estimate uses. Defaults to 500.

    Keyword Args:
        batch_shape (tuple of int): one window per batch element. Defaults to ``()``.
        min_scale (float): floor on each dimension's spread. Defaults to ``1e-6``.
        device (torch.device, optional): where the buffers live.

    Examples:
        >>> import torch
        >>> from torchrl_mbe.modules import KernelDensityNovelty
        >>> novelty = KernelDensityNovelty(window=200)
        >>> novelty.update(torch.cat([torch.randn(100, 2) - 3, torch.randn(100, 2) + 3]))  # two clusters
        >>> scores = novelty.score(torch.tensor([[-3.0, -3.0], [0.0, 0.0], [3.0, 3.0]]))
        >>> bool(scores[1] > scores[0]) and bool(scores[1] > scores[2])  # the gap between them is rare
        True
    """

    def __init__(
        self,
        num_features: int | None = None,
        window: int = 500,
        *,
        batch_shape: Sequence[int] = (),
        min_scale: float = 1e-6,
        device: torch.device | str | None = None,
    ) -> None:
        super().__init__(num_features, window, batch_shape=batch_shape, device=device)
        self.min_scale = float(min_scale)

    def score(self, states: torch.Tensor) -> torch.Tensor:
        """``-log`` of the kernel density at each state: higher = rarer; zeros while the window is empty."""
        if self._empty_eagerly():
            return states.new_zeros(states.shape[:-1])
        stored, filled = self._scored_window()
        offsets, spread = _offsets_in_window_spreads(self._check_shape(states), stored, filled, self.min_scale)
        dims = self.num_features
        count = self.num_stored if filled is None else filled.sum().clamp_min(1).to(offsets)
        scott = count ** (-1.0 / (dims + 4))  # bandwidth = spread * scott
        log_bandwidths = spread.log().sum(-1) + dims * _log(scott)
        log_kernels = -0.5 * (offsets / scott).square().sum(-1) - log_bandwidths - 0.5 * dims * math.log(2 * math.pi)
        if filled is not None:
            log_kernels = log_kernels.masked_fill(~filled, -torch.inf)
        return self._zeros_while_empty(-(torch.logsumexp(log_kernels, dim=-1) - _log(count)))


def _log(value: float | torch.Tensor) -> float | torch.Tensor:
    """``math.log`` of a count (eager scorers), ``torch.log`` of a tensor one (compiled scorers)."""
    return torch.log(value) if isinstance(value, torch.Tensor) else math.log(value)
