from __future__ import annotations

import numpy as np
import pytest

from torchrl_mbe.envs.registry import TASKS
from torchrl_mbe.report.metrics import episode_stats, grid_coverage, max_position, pairwise_coverage, running_average

MOUNTAINCAR = TASKS["mountaincar"].bounds


def cell_centers(low, high, bins):
    """One state at the center of every cell of a bins x bins grid over (low, high)."""
    axes = [lo + (np.arange(bins) + 0.5) * (hi - lo) / bins for lo, hi in zip(low, high)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 2)


class TestGridCoverage:
    def test_one_state_covers_one_cell(self):
        assert grid_coverage(np.array([[-0.5, 0.0]]), MOUNTAINCAR.plane_low, MOUNTAINCAR.plane_high) == 1 / 400

    def test_every_cell_center_covers_everything(self):
        states = cell_centers(MOUNTAINCAR.plane_low, MOUNTAINCAR.plane_high, 20)
        assert grid_coverage(states, MOUNTAINCAR.plane_low, MOUNTAINCAR.plane_high) == 1.0
        assert grid_coverage(states[::2], MOUNTAINCAR.plane_low, MOUNTAINCAR.plane_high) == 0.5

    def test_repeated_visits_count_once(self):
        states = np.tile([[-0.5, 0.0], [0.3, 0.05]], (1000, 1))
        assert grid_coverage(states, MOUNTAINCAR.plane_low, MOUNTAINCAR.plane_high) == 2 / 400

    def test_states_outside_the_box_clip_into_edge_cells(self):
        far_corners = np.array([[-5.0, -1.0], [5.0, 1.0], [-5.0, 1.0], [5.0, -1.0]])
        inside_corners = np.array([[-1.2, -0.07], [0.6, 0.07], [-1.2, 0.07], [0.6, -0.07]])
        low, high = MOUNTAINCAR.plane_low, MOUNTAINCAR.plane_high
        assert grid_coverage(far_corners, low, high) == 4 / 400
        assert grid_coverage(np.concatenate([far_corners, inside_corners]), low, high) == 4 / 400

    def test_bins_and_dims_choose_the_grid(self):
        states = np.array([[0.0, 9.0, 0.1], [0.0, 9.0, 0.9]])
        assert grid_coverage(states, (0.0, 0.0), (1.0, 1.0), bins=2, dims=(0, 2)) == 0.5
        assert grid_coverage(states, (0.0, 0.0), (1.0, 1.0), bins=10, dims=(0, 2)) == 2 / 100

    def test_no_states_cover_nothing(self):
        assert grid_coverage(np.zeros((0, 2)), (0.0, 0.0), (1.0, 1.0)) == 0.0

    @pytest.mark.parametrize(
        "states, low, high",
        [
            (np.zeros(2), (0.0, 0.0), (1.0, 1.0)),  # not (num_steps, obs_dim)
            (np.full((1, 2), np.nan), (0.0, 0.0), (1.0, 1.0)),
            (np.zeros((1, 2)), (0.0, 1.0), (1.0, 1.0)),  # empty box
        ],
    )
    def test_bad_input_is_rejected(self, states, low, high):
        with pytest.raises(ValueError):
            grid_coverage(states, low, high)


class TestPairwiseCoverage:
    def test_lunarlander_averages_over_continuous_pairs_and_ignores_legs(self):
        bounds = TASKS["lunarlander"].bounds
        state = np.zeros((1, 8))
        legs = np.array([[0, 0, 0, 0, 0, 0, 0, 0], [0, 0, 0, 0, 0, 0, 1, 1]], dtype=float)
        assert pairwise_coverage(state, bounds) == 1 / 400
        assert pairwise_coverage(legs, bounds) == 1 / 400

    def test_spreading_in_one_dim_shows_in_the_pairs_holding_it(self):
        bounds = TASKS["lunarlander"].bounds
        states = np.zeros((20, 8))
        low, high = bounds.low[0], bounds.high[0]
        states[:, 0] = low + (np.arange(20) + 0.5) * (high - low) / 20  # x visits all 20 bins
        # 5 of the 15 pairs hold x and see 20 cells; the other 10 see one.
        assert pairwise_coverage(states, bounds) == pytest.approx((5 * 20 + 10 * 1) / 400 / 15)

    def test_mountaincar_pairwise_equals_plane_coverage(self):
        states = np.random.default_rng(0).uniform(MOUNTAINCAR.low, MOUNTAINCAR.high, size=(300, 2))
        plane = grid_coverage(states, MOUNTAINCAR.plane_low, MOUNTAINCAR.plane_high)
        assert pairwise_coverage(states, MOUNTAINCAR) == plane


class TestEpisodeStats:
    def test_running_average_uses_fewer_episodes_at_the_start(self):
        np.testing.assert_allclose(running_average(np.array([1.0, 3.0, 5.0, 7.0]), window=3), [1.0, 2.0, 3.0, 5.0])

    def test_first_success_and_solved_episode(self):
        # MountainCar-like: 29 failures at -200, then -100 with the goal reached.
        returns = np.r_[np.full(29, -200.0), np.full(121, -100.0)]
        stats = episode_stats(returns, returns > -200, -110.0)
        assert stats.num_episodes == 150
        assert stats.first_success_episode == 30
        assert stats.num_successes == 121
        # window ending at i holds (129 - i) failures: average -100 - (129 - i) >= -110 from i = 119.
        assert stats.solved_episode == 119
        assert stats.best_running_average == -100.0
        assert stats.final_running_average == -100.0

    def test_a_run_shorter_than_the_window_is_never_solved(self):
        returns = np.full(50, -90.0)
        stats = episode_stats(returns, np.ones(50), -110.0)
        assert stats.first_success_episode == 1
        assert stats.solved_episode is None
        assert stats.best_running_average == stats.final_running_average == -90.0

    def test_best_average_ignores_lucky_partial_windows(self):
        returns = np.r_[500.0, np.zeros(9)]
        stats = episode_stats(returns, np.zeros(10), 475.0, window=5)
        assert stats.best_running_average == 100.0  # episodes 1-5, not episode 1 alone
        assert stats.final_running_average == 0.0

    def test_no_threshold_is_never_solved(self):
        assert episode_stats(np.zeros(200), np.ones(200), None).solved_episode is None

    def test_never_successful(self):
        stats = episode_stats(np.full(200, -200.0), np.zeros(200), -110.0)
        assert (stats.first_success_episode, stats.num_successes, stats.solved_episode) == (None, 0, None)

    def test_empty_table(self):
        stats = episode_stats(np.array([]), np.array([]), -110.0)
        assert stats.num_episodes == 0
        assert stats.best_running_average is None and stats.first_success_episode is None

    def test_mismatched_columns_are_rejected(self):
        with pytest.raises(ValueError, match="equal length"):
            episode_stats(np.zeros(3), np.zeros(2), 0.0)


def test_max_position():
    states = np.array([[-0.5, 0.0], [0.52, 0.01], [0.1, -0.02]])
    assert max_position(states) == 0.52
    assert max_position(states, dim=1) == 0.01
