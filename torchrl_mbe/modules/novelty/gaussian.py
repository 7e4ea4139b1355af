"""Gaussian densities of the window: the paper's full covariance, and the diagonal one (visit counts on one-hot states)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import nn

from torchrl_mbe.modules.novelty.window import RollingWindowNovelty

__all__ = ["DiagonalGaussianDensity", "GaussianDensity", "RollingGaussianDensity"]


class GaussianDensity(RollingWindowNovelty):
    """What every Gaussian density of the window shares: its mean, its normalizer, ``log_prob`` and ``score``.

    ``score(s) = -log N(s | loc, Sigma) = 0.5 * mahalanobis(s - loc) + log_normalizer``;
    a subclass fits ``loc``, the Mahalanobis form and ``log_normalizer`` in ``_refit``
    (:meth:`_store_log_normalizer` from ``log det Sigma``) and computes ``_mahalanobis``.
    Eager and compiled runs share this one scoring path.

    Keyword Args:
        min_variance (float): absolute floor on each variance. Defaults to ``1e-8``.
    """

    def __init__(
        self,
        num_features: int | None,
        window: int | None,
        *,
        batch_shape: Sequence[int] = (),
        min_variance: float = 1e-8,
        device: torch.device | str | None = None,
    ) -> None:
        super().__init__(None, window, batch_shape=batch_shape, device=device)
        if min_variance <= 0:
            raise ValueError(f"min_variance must be > 0, got {min_variance}.")
        self.min_variance = float(min_variance)
        if num_features is not None:
            self._allocate(int(num_features))

    def _allocate(self, num_features: int) -> None:
        super()._allocate(num_features)
        kwargs = {"dtype": torch.float64, "device": self.num_seen.device}
        self.register_buffer("loc", torch.zeros(*self.batch_shape, num_features, **kwargs))
        self.register_buffer("log_normalizer", torch.zeros(self.batch_shape, **kwargs))

    def log_prob(self, states: torch.Tensor) -> torch.Tensor:
        """``log N(s | mu_F, Sigma_F)`` per state; zeros while the window is empty."""
        if self._empty_eagerly():
            return states.new_zeros(states.shape[:-1])
        states = self._check_shape(states)
        self._refit_if_stale()
        mahalanobis = self._mahalanobis(states.to(self.loc) - self.loc)
        return self._zeros_while_empty((-0.5 * mahalanobis - self.log_normalizer).to(states.dtype))

    def score(self, states: torch.Tensor) -> torch.Tensor:
        """``-log_prob(states)``: higher = rarer."""
        return -self.log_prob(states)

    def _mahalanobis(self, centered: torch.Tensor) -> torch.Tensor:
        """``x^T Sigma^-1 x`` per centered state."""
        raise NotImplementedError

    def _store_log_normalizer(self, log_det: torch.Tensor) -> None:
        """Stores ``log((2 pi)^(D/2) sqrt(det Sigma))`` from ``log det Sigma``."""
        self.log_normalizer.copy_(0.5 * (log_det + self.num_features * math.log(2 * math.pi)))


class RollingGaussianDensity(GaussianDensity):
    """Multivariate Gaussian fitted to the last ``window`` visited states.

    The paper's novelty measure (Gou & Liu, "DQN with Model-Based Exploration"):
    ``N(s | mu_F, Sigma_F)`` with the empirical mean and the unbiased empirical
    covariance of the window ``S_F``; :meth:`score` is ``-log N``, so the planner's
    argmax of score is the paper's argmin of density.

    A window's covariance is singular when a state dimension is constant, when it
    holds fewer than ``num_features + 1`` distinct states, or when states repeat.
    Two scale-free repairs keep the density finite and meaningful, and leave a
    well-conditioned window untouched:

    * each variance is floored at ``min_variance`` (only constant dimensions are
      affected), and
    * the eigenvalues of the correlation matrix are floored at
      ``min_correlation_eigenvalue``: directions the window never moved in get a
      small but positive spread, so a prediction that leaves the window's
      subspace scores as very rare instead of infinitely rare.

    The factorization is computed once per window change, at the first score
    after it, and cached: scoring every candidate action of a step costs only
    matrix products, and window updates that are never scored cost no fit. With
    ``num_features <= window`` it is a float64 ``eigh`` of the ``D x D``
    correlation matrix, cached as a whitening matrix. With more features than
    the window holds states (one-hot DeepSea grids: ``D = N^2``), the correlation
    has rank below ``window``, so the same floored density comes from the
    ``eigh`` of the ``window x window`` Gram matrix, cached with the standardized
    window: ``O(window^2 D)`` instead of ``O(D^3)``, and as fast at
    ``D = window``, where the two paths meet (``bench/novelty.py``).

    Args:
        num_features (int, optional): size of a state vector; inferred from the first update if ``None``.
        window (int): the paper's F, number of recent states fitted. Defaults to 50.

    Keyword Args:
        batch_shape (tuple of int): one window per batch element. Defaults to ``()``.
        min_variance (float): absolute floor on each variance. Defaults to ``1e-8``.
        min_correlation_eigenvalue (float): floor on the correlation matrix's
            eigenvalues. Defaults to ``1e-6``.
        device (torch.device, optional): where the buffers live.

    Examples:
        >>> import torch
        >>> from torchrl_mbe import RollingGaussianDensity
        >>> density = RollingGaussianDensity(num_features=2, window=50)
        >>> density.update(torch.randn(100, 2))  # keeps the last 50
        >>> density.window_states().shape
        torch.Size([50, 2])
        >>> scores = density.score(torch.tensor([[0.0, 0.0], [5.0, 5.0]]))
        >>> bool(scores[1] > scores[0])  # the far state is rarer
        True
    """

    def __init__(
        self,
        num_features: int | None = None,
        window: int = 50,
        *,
        batch_shape: Sequence[int] = (),
        min_variance: float = 1e-8,
        min_correlation_eigenvalue: float = 1e-6,
        device: torch.device | str | None = None,
    ) -> None:
        if min_correlation_eigenvalue <= 0:
            raise ValueError(f"min_correlation_eigenvalue must be > 0, got {min_correlation_eigenvalue}.")
        self.min_correlation_eigenvalue = float(min_correlation_eigenvalue)
        super().__init__(num_features, window, batch_shape=batch_shape, min_variance=min_variance, device=device)

    def _allocate(self, num_features: int) -> None:
        super()._allocate(num_features)
        shape = (*self.batch_shape, num_features)
        kwargs = {"dtype": torch.float64, "device": self.num_seen.device}
        if self._fits_low_rank():
            self.register_buffer("std", torch.ones(shape, **kwargs))
            self.register_buffer(
                "standardized_window", torch.zeros(*self.batch_shape, self.window, num_features, **kwargs)
            )
            self.register_buffer("eigenvalues", torch.ones(*self.batch_shape, self.window, **kwargs))
            self.register_buffer(
                "gram_eigenvectors", torch.zeros(*self.batch_shape, self.window, self.window, **kwargs)
            )
        else:
            self.register_buffer("whitening", torch.zeros(*shape, num_features, **kwargs))

    def _fits_low_rank(self) -> bool:
        """Whether the fit is the eigenpairs of the window's Gram matrix (more features than states), not a whitening."""
        return self.num_features > self.window

    @property
    def covariance_matrix(self) -> torch.Tensor:
        """The regularized covariance the density uses, ``(*batch_shape, D, D)``."""
        self._refit_if_stale()
        if self._fits_low_rank():
            floor = self.min_correlation_eigenvalue
            eigenvectors = self.gram_eigenvectors @ self.standardized_window
            raised = (self.eigenvalues - floor).unsqueeze(-1) * eigenvectors
            correlation = eigenvectors.mT @ raised + floor * torch.eye(self.num_features).to(raised)
            return (self.std.unsqueeze(-1) * correlation * self.std.unsqueeze(-2)).to(self.states.dtype)
        inverse = torch.linalg.inv(self.whitening)
        return (inverse @ inverse.mT).to(self.states.dtype)

    def _mahalanobis(self, centered: torch.Tensor) -> torch.Tensor:
        return (self._low_rank_mahalanobis if self._fits_low_rank() else self._whitened_mahalanobis)(centered)

    def _whitened_mahalanobis(self, centered: torch.Tensor) -> torch.Tensor:
        whitened = (self.whitening @ centered.unsqueeze(-1)).squeeze(-1)
        return whitened.square().sum(-1)

    def _low_rank_mahalanobis(self, centered: torch.Tensor) -> torch.Tensor:
        """``|x|^2 / floor + sum_i (1 / lambda_i - 1 / floor) (u_i . x)^2`` with ``x = centered / std``.

        ``einsum``, unlike a broadcast ``@``, does not copy the window's matrices once per sample.
        """
        floor = self.min_correlation_eigenvalue
        standardized = centered / self.std
        window_products = torch.einsum("...fd,...d->...f", self.standardized_window, standardized)
        projections = torch.einsum("...if,...f->...i", self.gram_eigenvectors, window_products)
        spanned_correction = ((1 / self.eigenvalues - 1 / floor) * projections.square()).sum(-1)
        return standardized.square().sum(-1) / floor + spanned_correction

    def _refit(self) -> None:
        """Mean, factorization and normalizer of the window; slot order is fine, the fit ignores order."""
        moments = self._window_moments()
        if moments is None:
            return
        if self._fits_low_rank():
            self._refit_low_rank(*moments)
        else:
            self._refit_whitening(*moments)

    def _refit_whitening(self, loc: torch.Tensor, centered: torch.Tensor, degrees: torch.Tensor | int) -> None:
        """The whitening matrix of the floored correlation, from the ``eigh`` of the ``D x D`` correlation matrix."""
        covariance = centered.mT @ centered / degrees
        std = covariance.diagonal(dim1=-2, dim2=-1).clamp_min(self.min_variance).sqrt()
        eigenvalues, eigenvectors = torch.linalg.eigh(covariance / (std.unsqueeze(-1) * std.unsqueeze(-2)))
        eigenvalues = eigenvalues.clamp_min(self.min_correlation_eigenvalue)
        # Sigma = diag(std) V diag(lambda) V^T diag(std)  =>  W = diag(lambda^-1/2) V^T diag(1/std)
        whitening = (eigenvectors / eigenvalues.sqrt().unsqueeze(-2)).mT / std.unsqueeze(-2)
        self._store_fit(loc, whitening, eigenvalues.log().sum(-1) + 2 * std.log().sum(-1))

    def _refit_low_rank(self, loc: torch.Tensor, centered: torch.Tensor, degrees: torch.Tensor | int) -> None:
        """The floored correlation's top ``window`` eigenpairs, from the ``eigh`` of the window's Gram matrix.

        With ``Z = centered / std / sqrt(degrees)`` (``window x D``, the slots beyond
        the stored states zero), the correlation ``Z^T Z`` shares its nonzero
        eigenvalues ``lambda_i`` with ``Z Z^T`` (``window x window``), and its
        eigenvectors are ``u_i = Z^T v_i / sqrt(lambda_i)``, kept as the window
        ``Z sqrt(degrees)`` and the coordinates ``v_i / sqrt(lambda_i degrees)``:
        scoring a few states against them costs less than forming the ``u_i``.
        Flooring every eigenvalue at ``floor`` leaves the ``D - window`` others at
        ``floor``; a pair floored here gets weight 0, whatever its vector.
        """
        floor = self.min_correlation_eigenvalue
        std = (centered.square().sum(-2) / degrees).clamp_min(self.min_variance).sqrt()
        empty_slots = self.window - centered.shape[-2]
        standardized = nn.functional.pad(centered / std.unsqueeze(-2), (0, 0, 0, empty_slots))
        gram_eigenvalues, gram_eigenvectors = torch.linalg.eigh(standardized @ standardized.mT / degrees)
        eigenvalues = gram_eigenvalues.clamp_min(floor)
        self.loc.copy_(loc)
        self.std.copy_(std)
        self.standardized_window.copy_(standardized)
        self.eigenvalues.copy_(eigenvalues)
        self.gram_eigenvectors.copy_(gram_eigenvectors.mT / (eigenvalues * degrees).sqrt().unsqueeze(-1))
        null_space_log_det = (self.num_features - self.window) * math.log(floor)
        self._store_log_normalizer(eigenvalues.log().sum(-1) + null_space_log_det + 2 * std.log().sum(-1))

    def _window_moments(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | int] | None:
        """The window's mean, its states minus the mean (float64) and the degrees of freedom; ``None`` when empty."""
        if not torch.compiler.is_compiling():
            stored = self.states[..., : self.num_stored, :].to(torch.float64)
            if stored.shape[-2] == 0:
                return None
            loc = stored.mean(-2)
            return loc, stored - loc.unsqueeze(-2), max(stored.shape[-2] - 1, 1)
        # every slot, the empty ones weighing nothing (an empty window fits zeros, which no score reads)
        stored, filled = self._scored_window()
        stored, weights, count = stored.to(torch.float64), filled.to(torch.float64).unsqueeze(-1), filled.sum()
        loc = (stored * weights).sum(-2) / count.clamp_min(1)
        return loc, (stored - loc.unsqueeze(-2)) * weights, (count - 1).clamp_min(1)

    def _store_fit(self, loc: torch.Tensor, whitening: torch.Tensor, log_det: torch.Tensor) -> None:
        self.loc.copy_(loc)
        self.whitening.copy_(whitening)
        self._store_log_normalizer(log_det)


class DiagonalGaussianDensity(GaussianDensity):
    """Gaussian with a diagonal covariance fitted to the last ``window`` visited states, or to all of them.

    ``score(s) = -log N(s | mu_F, diag(sigma_F^2))``: :class:`RollingGaussianDensity`
    with the correlations between dimensions dropped, so that a window whose
    states move along a line is not read as a thin ellipse.

    The fit keeps running sums of the states and of their squares (float64):
    each state is added as it enters the window and subtracted as it leaves, so
    an update and a refit cost ``O(D)``, whatever the window. With
    ``window=None`` every state given counts and none is stored (``O(D)``
    memory): on one-hot states (DeepSea's grid) the score then ranks cells by
    how often they were ever visited, as a visit count does.

    ``added_variance`` is added to every variance before the floor (scikit-learn's
    ``reg_covar``). The floor ties every dimension whose variance is below it; the
    addition keeps their order. Counting one-hot cells over ``T`` visits, a cell
    visited ``n`` times then scores about ``T / (n + added_variance * T)``, so a
    prediction that lands on a cell visited once still outranks one that lands on
    a cell visited five times, however large ``T`` grows, while an error ``e``
    in a never-visited dimension adds at most ``e^2 / added_variance``.

    Keyword Args:
        added_variance (float): added to each dimension's variance. Defaults to ``0``.
        **kwargs: ``batch_shape``, ``min_variance``, ``device``, as for :class:`RollingGaussianDensity`.

    Examples:
        >>> import torch
        >>> from torchrl_mbe.modules import DiagonalGaussianDensity
        >>> density = DiagonalGaussianDensity(window=50)
        >>> density.update(torch.randn(100, 2))
        >>> scores = density.score(torch.tensor([[0.0, 0.0], [5.0, 5.0]]))
        >>> bool(scores[1] > scores[0])
        True
        >>> cells = torch.eye(3)
        >>> counts = DiagonalGaussianDensity(window=None)  # every visit counts
        >>> counts.update(cells[[0, 0, 0, 1, 0, 0, 1, 2]])
        >>> counts.score(cells).argsort(descending=True).tolist()  # the cell visited least first
        [2, 1, 0]
        >>> cells = torch.eye(4)
        >>> visits = cells[[0] * 200 + [1] * 4 + [2]]  # cells 1, 2 and 3 visited 4, 1 and 0 times
        >>> floored = DiagonalGaussianDensity(window=None, min_variance=0.05)
        >>> floored.update(visits)
        >>> [round(score, 1) for score in floored.score(cells[1:]).tolist()]  # all three at the floor: close
        [16.8, 17.1, 17.2]
        >>> added = DiagonalGaussianDensity(window=None, added_variance=0.05)
        >>> added.update(visits)
        >>> [round(score, 1) for score in added.score(cells[1:]).tolist()]  # apart
        [11.5, 13.6, 14.5]
    """

    counts_every_state = True

    def __init__(
        self, num_features: int | None = None, window: int | None = 50, *, added_variance: float = 0.0, **kwargs
    ) -> None:
        if added_variance < 0:
            raise ValueError(f"added_variance must be >= 0, got {added_variance}.")
        super().__init__(num_features, window, **kwargs)
        self.added_variance = float(added_variance)

    def extra_repr(self) -> str:
        return f"{super().extra_repr()}, min_variance={self.min_variance:g}, added_variance={self.added_variance:g}"

    def _allocate(self, num_features: int) -> None:
        super()._allocate(num_features)
        shape = (*self.batch_shape, num_features)
        kwargs = {"dtype": torch.float64, "device": self.num_seen.device}
        self.register_buffer("state_sum", torch.zeros(shape, **kwargs))
        self.register_buffer("state_square_sum", torch.zeros(shape, **kwargs))
        self.register_buffer("inverse_std", torch.ones(shape, **kwargs))

    def _before_push(self, states: torch.Tensor) -> None:
        """Adds the entering states to the sums and takes out the ones they overwrite in the window."""
        if self.window is not None:
            self._subtract_leaving(states.shape[0])
        entering = states.to(torch.float64)
        self.state_sum.add_(entering.sum(0))
        self.state_square_sum.add_(entering.square().sum(0))

    def _subtract_leaving(self, count: int) -> None:
        """Takes the states that the next ``count`` pushes overwrite out of the sums."""
        positions = self.num_seen + torch.arange(count, device=self.num_seen.device)
        held = (positions >= self.window).to(torch.float64).unsqueeze(-1)  # the slot holds an older state
        leaving = self.states[..., self._next_slots(count), :].to(torch.float64) * held
        self.state_sum.sub_(leaving.sum(-2))
        self.state_square_sum.sub_(leaving.square().sum(-2))

    def reset(self) -> None:
        super().reset()
        if self.num_features is not None:
            self.state_sum.zero_()
            self.state_square_sum.zero_()

    def _refit(self) -> None:
        """Mean and per-dimension spread from the running sums: no ``D x D`` covariance, no ``eigh``.

        The same density as the full Gaussian with its correlation matrix set to the
        identity (whose eigenvalues are 1), the unbiased variance plus ``added_variance``,
        floored at ``min_variance``.
        """
        count = self.num_seen if self.window is None else self.num_seen.clamp_max(self.window)
        count = count.to(torch.float64)
        loc = self.state_sum / count.clamp_min(1)
        variance = (self.state_square_sum - count * loc.square()) / (count - 1).clamp_min(1)
        std = (variance + self.added_variance).clamp_min(self.min_variance).sqrt()
        self.loc.copy_(loc)
        self.inverse_std.copy_(1 / std)
        self._store_log_normalizer(2 * std.log().sum(-1))

    def _mahalanobis(self, centered: torch.Tensor) -> torch.Tensor:
        return (centered * self.inverse_std).square().sum(-1)

    @property
    def covariance_matrix(self) -> torch.Tensor:
        """The floored diagonal covariance the density uses, ``(*batch_shape, D, D)``."""
        self._refit_if_stale()
        return torch.diag_embed(self.inverse_std.pow(-2)).to(torch.float32)

    def _load_from_state_dict(self, state_dict: dict, prefix: str, *args, **kwargs) -> None:
        if self.num_features is None and prefix + "state_sum" in state_dict:  # window=None keeps no states to size from
            self._allocate(state_dict[prefix + "state_sum"].shape[-1])
        if prefix + "whitening" in state_dict:  # saved before the running sums: they are its window's
            self._sums_from_saved_window(state_dict, prefix)
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def _sums_from_saved_window(self, state_dict: dict, prefix: str) -> None:
        state_dict.pop(prefix + "whitening")
        stored = state_dict[prefix + "states"][..., : min(int(state_dict[prefix + "num_seen"]), self.window), :].to(
            torch.float64
        )
        state_dict[prefix + "state_sum"] = stored.sum(-2)
        state_dict[prefix + "state_square_sum"] = stored.square().sum(-2)
        state_dict[prefix + "inverse_std"] = torch.ones_like(stored.sum(-2))
        state_dict[prefix + "fit_stale"] = torch.ones((), dtype=torch.bool)
