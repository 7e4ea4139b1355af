from __future__ import annotations

import functools

import pytest
import torch
from torch.distributions import MultivariateNormal

from torchrl_mbe import (
    DiagonalGaussianDensity,
    GaussianKernelNovelty,
    KernelDensityNovelty,
    KNearestNovelty,
    RollingGaussianDensity,
    VisitCounts,
)


def correlated_states(num: int) -> torch.Tensor:
    mixing = torch.tensor([[1.0, 0.0, 0.0], [0.8, 0.5, 0.0], [-0.3, 0.2, 2.0]])
    return torch.randn(num, 3) @ mixing.T + torch.tensor([1.0, -2.0, 0.5])


def test_gaussian_matches_torch_multivariate_normal_on_a_well_conditioned_window():
    states = correlated_states(200)
    density = RollingGaussianDensity(3, window=50)
    density.update(states)
    window = states[-50:]
    reference = MultivariateNormal(window.mean(0), covariance_matrix=torch.cov(window.T))
    queries = correlated_states(20) * 1.5
    torch.testing.assert_close(density.log_prob(queries), reference.log_prob(queries), atol=1e-4, rtol=1e-4)
    torch.testing.assert_close(density.score(queries), -reference.log_prob(queries), atol=1e-4, rtol=1e-4)
    torch.testing.assert_close(density.covariance_matrix, torch.cov(window.T), atol=1e-5, rtol=1e-4)


def test_window_keeps_the_last_states_in_visiting_order_across_wraparound():
    density = RollingGaussianDensity(2, window=5)
    states = torch.arange(24.0).reshape(12, 2)
    for chunk in states.split(3):
        density.update(chunk)
    torch.testing.assert_close(density.window_states(), states[-5:])
    assert density.num_stored == 5


@pytest.mark.parametrize(
    "window_states",
    [
        torch.stack([torch.linspace(0, 1, 10), torch.full((10,), 3.0)], -1),  # constant dimension
        torch.tensor([[0.0, 1.0], [1.0, 2.0]]),  # fewer states than num_features + 1 ... on a line
        torch.tensor([[0.5, 0.5]] * 10),  # duplicates only
        torch.tensor([[0.5, 0.5]]),  # a single state
    ],
    ids=["constant-dim", "collinear", "duplicates", "single-state"],
)
def test_gaussian_stays_finite_and_ranks_by_distance_on_singular_windows(window_states):
    density = RollingGaussianDensity(2, window=50)
    density.update(window_states)
    center = window_states.mean(0)
    near, far = center + 1e-3, center + 1.0
    scores = density.score(torch.stack([center, near, far]))
    assert torch.isfinite(scores).all()
    assert scores[0] < scores[1] < scores[2]


def test_empty_window_scores_every_state_equally():
    density = RollingGaussianDensity(2, window=10)
    assert torch.equal(density.score(torch.randn(4, 2)), torch.zeros(4))


def test_gaussian_uses_correlation_not_only_distance():
    # States along the diagonal: a point on the diagonal is more likely than one
    # equally far from the mean but across it, which a distance cannot tell.
    t = torch.linspace(-1, 1, 50)
    density = RollingGaussianDensity(2, window=50)
    density.update(torch.stack([t, t + 0.05 * torch.randn(50)], -1))
    along, across = torch.tensor([0.7, 0.7]), torch.tensor([0.7, -0.7])
    assert density.score(along) < density.score(across)


def test_per_environment_windows_are_independent():
    density = RollingGaussianDensity(2, window=4, batch_shape=(3,))
    visits = torch.randn(6, 3, 2)  # 6 steps of 3 envs
    density.update(visits)
    for env in range(3):
        torch.testing.assert_close(density.window_states()[env], visits[-4:, env])
    candidates = torch.randn(5, 3, 2)  # 5 candidate states per env
    assert density.score(candidates).shape == (5, 3)
    single = RollingGaussianDensity(2, window=4)
    single.update(visits[:, 1])
    torch.testing.assert_close(density.score(candidates)[:, 1], single.score(candidates[:, 1]))


def test_state_dict_round_trip_restores_window_and_scores():
    density = RollingGaussianDensity(2, window=20)
    density.update(torch.randn(30, 2))
    restored = RollingGaussianDensity(2, window=20)
    restored.load_state_dict(density.state_dict())
    queries = torch.randn(7, 2)
    torch.testing.assert_close(restored.score(queries), density.score(queries))
    assert restored.num_stored == 20


def test_bad_shapes_and_windows_are_rejected_with_a_clear_message():
    with pytest.raises(ValueError, match="window must be an integer >= 2"):
        RollingGaussianDensity(2, window=1)
    with pytest.raises(ValueError, match=r"expects states of shape"):
        RollingGaussianDensity(2).update(torch.zeros(4, 3))


def test_kernel_novelty_is_minus_the_kernel_sum():
    novelty = GaussianKernelNovelty(2, window=3, bandwidth=0.5)
    window = torch.tensor([[0.0, 0.0], [1.0, 0.0], [0.0, 2.0]])
    novelty.update(window)
    query = torch.tensor([[0.5, 0.5]])
    expected = -torch.exp(-0.5 * ((query - window) / 0.5).square().sum(-1)).sum()
    torch.testing.assert_close(novelty.score(query), expected.reshape(1))
    assert novelty.score(torch.tensor([5.0, 5.0])) > novelty.score(torch.tensor([0.0, 0.0]))


def test_scores_do_not_depend_on_which_updates_were_scored():
    visits = correlated_states(120).split(7)
    queries = correlated_states(9) * 1.5
    every_update_scored, never_scored = RollingGaussianDensity(3, window=50), RollingGaussianDensity(3, window=50)
    for chunk in visits:
        every_update_scored.update(chunk)
        every_update_scored.score(queries)
        never_scored.update(chunk)
    assert torch.equal(never_scored.score(queries), every_update_scored.score(queries))
    assert torch.equal(never_scored.covariance_matrix, every_update_scored.covariance_matrix)


def test_the_gaussian_is_fitted_once_per_window_change_at_the_first_score(monkeypatch):
    density = RollingGaussianDensity(2, window=10)
    fits = []
    original_refit = density._refit
    monkeypatch.setattr(density, "_refit", lambda: fits.append(1) or original_refit())
    for _ in range(5):
        density.update(torch.randn(2))
    assert not fits
    density.score(torch.randn(3, 2))
    density.score(torch.randn(3, 2))
    assert len(fits) == 1


@pytest.mark.parametrize("scored_before_saving", [True, False], ids=["fitted", "stale"])
def test_a_loaded_state_dict_scores_the_same(scored_before_saving):
    density = RollingGaussianDensity(3, window=20)
    density.update(correlated_states(30))
    queries = correlated_states(7) * 1.5
    if scored_before_saving:
        density.score(queries)
    restored = RollingGaussianDensity(3, window=20)
    restored.update(correlated_states(5))
    restored.score(queries)  # a fit of another window, which loading must replace
    restored.load_state_dict(density.state_dict())
    assert torch.equal(restored.score(queries), density.score(queries))


class DenseGaussianDensity(RollingGaussianDensity):
    """The whitening path (``eigh`` of the ``D x D`` correlation) at every size: the low-rank path's reference."""

    def _fits_low_rank(self) -> bool:
        return False


def with_constant_and_repeated_states(states: torch.Tensor) -> torch.Tensor:
    """``states`` with feature 3 constant and the last 5 states visited again."""
    states = states.clone()
    states[..., 3] = 2.0
    return torch.cat([states, states[-5:]])


def one_hot_path(num_cells: int, steps: int, batch: int) -> torch.Tensor:
    """DeepSea-like one-hot states (rows of the identity), visiting only the first third of the cells."""
    return torch.eye(num_cells)[torch.randint(0, num_cells // 3, (steps, batch))]


LOW_RANK_WINDOWS = {  # (steps, batch, features) states, window 50
    "partly-filled": lambda: with_constant_and_repeated_states(torch.randn(20, 3, 120)),
    "wrapped-round": lambda: with_constant_and_repeated_states(torch.randn(130, 3, 120)),
    "one-hot-deepsea-20": lambda: one_hot_path(400, 70, 3),
    "single-state": lambda: torch.randn(1, 3, 120),
}


@pytest.mark.parametrize("make_window", LOW_RANK_WINDOWS.values(), ids=LOW_RANK_WINDOWS.keys())
def test_the_low_rank_fit_gives_the_density_of_the_dense_eigh_fit(make_window):
    visits = make_window()
    num_features = visits.shape[-1]
    low_rank, dense = (
        RollingGaussianDensity(window=50, batch_shape=(3,)),
        DenseGaussianDensity(window=50, batch_shape=(3,)),
    )
    for density in (low_rank, dense):
        density.update(visits)
    assert "gram_eigenvectors" in low_rank.state_dict() and "whitening" not in low_rank.state_dict()
    unseen_one_hot = torch.eye(num_features)[torch.randint(0, num_features, (5, 3))]
    queries = torch.cat([visits[-5:], unseen_one_hot, torch.randn(5, 3, num_features)]).double()
    torch.testing.assert_close(low_rank.log_prob(queries), dense.log_prob(queries), rtol=1e-8, atol=1e-6)
    torch.testing.assert_close(
        low_rank.covariance_matrix, regularized_covariance(low_rank.window_states()), rtol=1e-5, atol=1e-10
    )


def regularized_covariance(
    window: torch.Tensor, min_variance: float = 1e-8, min_eigenvalue: float = 1e-6
) -> torch.Tensor:
    """The class docstring's covariance, from its definition: variances floored, correlation eigenvalues floored."""
    window = window.double()
    centered = window - window.mean(-2, keepdim=True)
    covariance = centered.mT @ centered / max(window.shape[-2] - 1, 1)
    std = covariance.diagonal(dim1=-2, dim2=-1).clamp_min(min_variance).sqrt()
    eigenvalues, eigenvectors = torch.linalg.eigh(covariance / (std.unsqueeze(-1) * std.unsqueeze(-2)))
    correlation = eigenvectors @ torch.diag_embed(eigenvalues.clamp_min(min_eigenvalue)) @ eigenvectors.mT
    return (std.unsqueeze(-1) * correlation * std.unsqueeze(-2)).float()


def test_the_fit_is_low_rank_exactly_when_there_are_more_features_than_window_slots():
    def buffers(num_features: int) -> set[str]:
        return set(RollingGaussianDensity(num_features, window=50).state_dict())

    low_rank_fit = {"std", "standardized_window", "eigenvalues", "gram_eigenvectors"}
    assert "whitening" in buffers(50) and not low_rank_fit & buffers(50)
    assert low_rank_fit <= buffers(51) and "whitening" not in buffers(51)
    diagonal_fit = set(DiagonalGaussianDensity(51, window=50).state_dict())
    assert "inverse_std" in diagonal_fit and not ({"whitening"} | low_rank_fit) & diagonal_fit  # no D x D matrix either


def test_a_low_rank_fit_travels_in_the_state_dict_to_a_fresh_density():
    density = RollingGaussianDensity(window=50, batch_shape=(3,))
    density.update(one_hot_path(400, 70, 3))
    queries = one_hot_path(400, 2, 3)
    scores = density.score(queries)
    fresh = RollingGaussianDensity(window=50, batch_shape=(3,))
    fresh.load_state_dict(density.state_dict())
    assert not fresh.fit_stale and torch.equal(fresh.score(queries), scores)


HASHED_COUNTS = functools.partial(VisitCounts, bits=8)  # counts of vectors that are not one-hot: SimHash buckets
ALL_SCORERS = [
    RollingGaussianDensity,
    GaussianKernelNovelty,
    DiagonalGaussianDensity,
    KNearestNovelty,
    KernelDensityNovelty,
]


@pytest.mark.parametrize("scorer_cls", ALL_SCORERS)
def test_scorers_infer_the_state_size_from_the_first_update_and_restore_into_a_fresh_one(scorer_cls):
    scorer = scorer_cls(window=20, batch_shape=(3,))
    assert torch.equal(scorer.score(torch.ones(5, 3, 4)), torch.zeros(5, 3))  # empty window: nothing is rarer
    states = torch.randn(30, 3, 4)
    scorer.update(states)
    assert scorer.num_features == 4 and torch.equal(scorer.window_states(), states[-20:].movedim(0, -2))
    fresh = scorer_cls(window=20, batch_shape=(3,))
    fresh.load_state_dict(scorer.state_dict())
    probe = torch.randn(7, 3, 4)
    assert torch.allclose(fresh.score(probe), scorer.score(probe))


@pytest.mark.parametrize(
    ("scorer_cls", "num_features"),
    [(scorer_cls, 2) for scorer_cls in ALL_SCORERS] + [(RollingGaussianDensity, 8)],  # 8 > window: the low-rank fit
    ids=[scorer_cls.__name__ for scorer_cls in ALL_SCORERS] + ["RollingGaussianDensity-low-rank"],
)
def test_every_scorer_compiles_with_fullgraph_and_scores_as_it_does_eagerly(scorer_cls, num_features):
    scorer = scorer_cls(num_features, window=6, batch_shape=(3,))
    compiled_score = torch.compile(scorer.score, fullgraph=True, backend="aot_eager")
    queries = torch.randn(4, 3, num_features)
    for visits in (0, 2, 4, 3):  # empty, 2 of 6 slots (fewer than KNearestNovelty's k), 6, wrapped round
        scorer.update(torch.randn(visits, 3, num_features))
        eager = scorer.score(queries)  # first: a compiled score refits the Gaussian its own way
        torch.testing.assert_close(compiled_score(queries), eager, rtol=1e-5, atol=1e-5)
    scorer.reset()
    assert torch.equal(compiled_score(queries), torch.zeros(4, 3))


@pytest.mark.parametrize("scorer_cls", [*ALL_SCORERS, HASHED_COUNTS])
def test_every_scorer_keeps_one_window_per_env_through_a_collector_with_batched_envs(scorer_cls):
    from torchrl.collectors import Collector
    from torchrl.modules import MLP, QValueActor

    from torchrl_mbe import DynamicsModel, ModelBasedExplorationPolicy, NoveltyPlanner, make_env

    env = make_env("mountaincar", num_envs=4, seed=0)
    spec = env.action_spec_unbatched
    novelty = scorer_cls(window=50, batch_shape=(4,))
    actor = QValueActor(MLP(out_features=3, num_cells=[8]), spec=spec, in_keys=["observation"])
    policy = ModelBasedExplorationPolicy(actor, NoveltyPlanner(DynamicsModel(2, spec), novelty, spec))
    collector = Collector(env, policy, frames_per_batch=40, total_frames=-1)
    batch = next(iter(collector))
    assert novelty.num_features == 2 and novelty.num_stored == 10
    assert torch.equal(novelty.window_states(), batch["observation"])  # one window per env, in visiting order
    collector.shutdown()


@pytest.mark.parametrize("scorer_cls", [*ALL_SCORERS, HASHED_COUNTS])
def test_every_scorer_scores_a_populations_windows_apart(scorer_cls):
    # batch (num_envs, M) = (4, 3): changing member 1's visits changes member 1's scores, and no other's
    visits = torch.randn(60, 4, 3, 8)
    changed = visits.clone()
    changed[:, :, 1] = changed[:, :, 1] * 3 + 1
    scores = []
    for states in (visits, changed):
        novelty = scorer_cls(8, window=50, batch_shape=(4, 3))
        novelty.update(states)
        scores.append(novelty.score(torch.randn(5, 4, 3, 8, generator=torch.Generator().manual_seed(0))))
    assert torch.equal(scores[0][:, :, [0, 2]], scores[1][:, :, [0, 2]])
    assert not torch.equal(scores[0][:, :, 1], scores[1][:, :, 1])


def test_diagonal_gaussian_is_the_sum_of_per_dimension_normal_log_densities():
    window = torch.randn(40, 2, 3) * torch.tensor([1.0, 10.0, 0.1])
    density = DiagonalGaussianDensity(window=40, batch_shape=(2,))
    density.update(window)
    states = torch.randn(5, 2, 3)
    expected = (
        -torch.distributions.Normal(window.double().mean(0), window.double().std(0)).log_prob(states.double()).sum(-1)
    )
    assert torch.allclose(density.score(states).double(), expected, atol=1e-4)


def test_diagonal_gaussian_running_sums_fit_exactly_the_states_in_the_window_as_it_wraps():
    density = DiagonalGaussianDensity(window=30, batch_shape=(2,))
    visited = torch.randn(95, 2, 3) * torch.tensor([1.0, 10.0, 0.1]) + 5.0
    states = torch.randn(5, 2, 3)
    for end in range(5, 96, 5):  # pushes of 5, wrapping the window three times
        density.update(visited[end - 5 : end])
        window = visited[max(end - 30, 0) : end].double()
        expected = -torch.distributions.Normal(window.mean(0), window.std(0)).log_prob(states.double()).sum(-1)
        torch.testing.assert_close(density.score(states).double(), expected, rtol=1e-6, atol=1e-3)


def test_diagonal_gaussian_without_a_window_fits_every_state_and_stores_none():
    density = DiagonalGaussianDensity(window=None)
    visited = torch.randn(500, 3) * torch.tensor([1.0, 10.0, 0.1])
    for chunk in visited.split(64):
        density.update(chunk)
    assert density.num_stored == 500 and density.states is None
    states = torch.randn(5, 3)
    expected = (
        -torch.distributions.Normal(visited.double().mean(0), visited.double().std(0)).log_prob(states.double()).sum(-1)
    )
    torch.testing.assert_close(density.score(states).double(), expected, rtol=1e-6, atol=1e-3)
    fresh = DiagonalGaussianDensity(window=None)
    fresh.load_state_dict(density.state_dict())
    assert torch.equal(fresh.score(states), density.score(states))
    with pytest.raises(ValueError, match="window=None"):
        density.window_states()


def test_without_a_window_the_diagonal_gaussian_ranks_one_hot_cells_by_how_often_they_were_visited():
    cells = torch.eye(6)
    visits = torch.tensor([40, 1, 7, 3, 0, 12])  # cell 4 never visited
    density = DiagonalGaussianDensity(window=None)
    density.update(cells.repeat_interleave(visits, dim=0)[torch.randperm(int(visits.sum()))])
    assert density.score(cells).argsort(descending=True).tolist() == visits.argsort().tolist()


def test_an_added_variance_keeps_the_visit_order_that_a_floor_ties_when_predictions_are_slightly_off():
    cells = torch.eye(8)
    visits = torch.tensor([2000, 1, 4, 16, 0, 0, 0, 0])  # cells 1-3 visited under 1% of the time
    predictions = cells[[1, 2, 3]].clone()
    predictions[2, 5:] = 0.1  # the prediction of the most visited of the three is off in never-visited cells
    rankings = {}
    for name, density in {
        "floor": DiagonalGaussianDensity(window=None, min_variance=1e-2),
        "added": DiagonalGaussianDensity(window=None, added_variance=1e-2),
    }.items():
        density.update(cells.repeat_interleave(visits, dim=0))
        rankings[name] = density.score(predictions).argsort(descending=True).tolist()
    assert rankings == {"floor": [2, 0, 1], "added": [0, 1, 2]}  # the floor ranks the error; the addition, the visits
    with pytest.raises(ValueError, match="added_variance must be >= 0"):
        DiagonalGaussianDensity(added_variance=-1.0)


def test_the_diagonal_gaussian_over_every_state_compiles_with_fullgraph_and_scores_as_it_does_eagerly():
    density = DiagonalGaussianDensity(4, window=None, batch_shape=(3,))
    compiled_score = torch.compile(density.score, fullgraph=True, backend="aot_eager")
    queries = torch.randn(4, 3, 4)
    for visits in (0, 2, 5):
        density.update(torch.randn(visits, 3, 4))
        eager = density.score(queries)
        torch.testing.assert_close(compiled_score(queries), eager, rtol=1e-5, atol=1e-5)
    density.reset()
    assert torch.equal(compiled_score(queries), torch.zeros(4, 3))


def test_only_the_running_moment_scorer_accepts_an_unbounded_window():
    with pytest.raises(ValueError, match="RollingGaussianDensity scores against stored states"):
        RollingGaussianDensity(window=None)


def test_a_diagonal_gaussian_saved_with_a_whitening_matrix_loads_and_scores_its_window():
    density = DiagonalGaussianDensity(window=20)
    density.update(torch.randn(35, 3))
    states = torch.randn(4, 3)
    old_layout = {
        key: value
        for key, value in density.state_dict().items()
        if key not in ("state_sum", "state_square_sum", "inverse_std")
    }
    old_layout["whitening"] = torch.eye(3, dtype=torch.float64)  # what an earlier version saved beside the window
    fresh = DiagonalGaussianDensity(3, window=20)
    fresh.load_state_dict(old_layout)
    torch.testing.assert_close(fresh.score(states), density.score(states))


def test_k_nearest_score_is_the_mean_scaled_distance_to_the_k_closest_stored_states():
    stored = torch.tensor([[0.0, 0.0], [0.0, 2.0], [4.0, 0.0], [4.0, 2.0]])
    novelty = KNearestNovelty(window=4, k=2)
    novelty.update(stored)
    scale = stored.std(0, correction=0)  # (2, 1) per dimension
    state = torch.tensor([[1.0, 0.0]])
    distances = ((state - stored) / scale).norm(dim=-1).sort().values
    assert torch.allclose(novelty.score(state), distances[:2].mean().unsqueeze(0))


def test_kernel_density_is_minus_the_log_of_a_scotts_rule_gaussian_mixture_over_the_window():
    window = torch.randn(300, 2, 3) * torch.tensor([1.0, 10.0, 0.1])
    novelty = KernelDensityNovelty(window=300, batch_shape=(2,))
    novelty.update(window)
    bandwidth = window.std(0, correction=0) * 300 ** (-1 / 7)  # (2, 3): per env and dimension
    mixture = torch.distributions.MixtureSameFamily(
        torch.distributions.Categorical(torch.ones(2, 300)),
        torch.distributions.Independent(torch.distributions.Normal(window.movedim(0, 1), bandwidth.unsqueeze(1)), 1),
    )
    states = torch.randn(5, 2, 3)
    assert torch.allclose(novelty.score(states), -mixture.log_prob(states), atol=1e-4)


def test_kernel_density_sees_two_clusters_where_the_gaussian_sees_one_blob():
    clusters = torch.cat([torch.randn(200, 2) * 0.3 - 3, torch.randn(200, 2) * 0.3 + 3])
    kde, gaussian = KernelDensityNovelty(window=400), RollingGaussianDensity(window=400)
    for scorer in (kde, gaussian):
        scorer.update(clusters)
    between, inside = torch.tensor([[0.0, 0.0]]), torch.tensor([[3.0, 3.0]])
    assert kde.score(between) > kde.score(inside)  # the empty gap is rare
    assert gaussian.score(between) < gaussian.score(inside)  # the blob's centre looks most familiar


def test_visit_counts_give_each_one_hot_state_the_bonus_of_its_visits_in_the_window():
    cells = torch.eye(5)
    visited = [0, 1, 1, 2, 2, 2, 3, 0, 0]
    rolling, every = VisitCounts(5, window=4), VisitCounts(5)
    for cell in visited:  # one at a time, so the rolling window wraps round
        rolling.update(cells[[cell]])
        every.update(cells[[cell]])
    last_four = torch.tensor([visited[-4:].count(cell) for cell in range(5)], dtype=torch.float32)
    all_visits = torch.tensor([visited.count(cell) for cell in range(5)], dtype=torch.float32)
    torch.testing.assert_close(rolling.score(cells), (last_four + 1).rsqrt())
    torch.testing.assert_close(every.score(cells), (all_visits + 1).rsqrt())
    assert every.score(cells).argmax() == 4  # never visited: the highest bonus, 1


def test_visit_counts_read_a_prediction_off_the_cells_as_a_distribution_over_its_positive_entries():
    counts = VisitCounts(4)
    counts.update(torch.eye(4)[[0, 0, 0, 1]])  # bonuses 0.5, 0.71, 1, 1
    bonus = (counts.counts + 1).rsqrt()
    predictions = torch.tensor(
        [
            [0.5, 0.5, 0.0, 0.0],  # a probability vector: its expected bonus
            [0.9, 0.0, -0.6, 0.0],  # an offset pushed an entry negative: it weighs nothing
            [3.0, 0.0, 1.0, 0.0],  # positive entries summing past 1: scaled to a distribution
            [0.0, 0.0, 0.0, 0.0],  # DeepSea's zeros after the last row
        ]
    )
    expected = torch.stack([bonus[:2].mean(), 0.9 * bonus[0], 0.75 * bonus[0] + 0.25 * bonus[2], torch.tensor(0.0)])
    torch.testing.assert_close(counts.score(predictions), expected)


def test_visit_counts_hash_near_states_together_and_restore_into_a_fresh_scorer():
    counts = VisitCounts(3, bits=12)
    states = torch.randn(40, 3)
    counts.update(states)
    assert counts.counts.sum() == 40
    assert counts.score(states[:1] * 1.001) == counts.score(states[:1])  # same direction: the same bucket
    fresh = VisitCounts(bits=12)  # the state size and the projection come from the state dict
    fresh.load_state_dict(counts.state_dict())
    probe = torch.randn(10, 3)
    assert torch.equal(fresh.score(probe), counts.score(probe))


def test_visit_counts_refuse_a_code_length_they_cannot_hold():
    with pytest.raises(ValueError, match="bits must be an integer from 1 to 24"):
        VisitCounts(3, bits=40)
