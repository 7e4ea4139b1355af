"""Comparisons across tasks: interquartile means, stratified bootstrap intervals, performance profiles, the report's section."""

from __future__ import annotations

import numpy as np
import pytest
from test_report import write_run

from torchrl_mbe.report import load_runs, main
from torchrl_mbe.report.across import budget_fractions, normalized_scores
from torchrl_mbe.report.intervals import iqm, performance_profile, stratified_bootstrap_ci


def test_the_interquartile_mean_ignores_the_quarter_of_seeds_at_each_end():
    scores = np.array([0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 1.1, 1.2])
    with_outliers = scores.copy()
    with_outliers[[0, -1]] = [-1_000.0, 1_000.0]
    assert iqm(scores) == pytest.approx(0.85) and iqm(with_outliers) == pytest.approx(0.85)


def test_the_interval_holds_the_estimate_narrows_with_less_spread_and_repeats_with_its_seed():
    rng = np.random.default_rng(0)
    wide = {"a": rng.normal(0.0, 1.0, 10), "b": rng.normal(1.0, 1.0, 10)}
    narrow = {task: seeds.mean() + 0.1 * (seeds - seeds.mean()) for task, seeds in wide.items()}
    point, low, high = stratified_bootstrap_ci(wide)
    narrow_point, narrow_low, narrow_high = stratified_bootstrap_ci(narrow)
    assert low < point < high and narrow_low < narrow_point < narrow_high
    assert narrow_high - narrow_low < 0.2 * (high - low)
    assert stratified_bootstrap_ci(wide) == (point, low, high)


def test_seeds_are_resampled_within_their_task():
    # Two tasks whose seeds agree: any resample within tasks gives the same IQM; across tasks it would not.
    point, low, high = stratified_bootstrap_ci({"a": np.zeros(6), "b": np.ones(2)}, statistic=np.mean)
    assert point == low == high == pytest.approx(0.25)


def test_a_performance_profile_weighs_every_task_the_same_and_never_rises():
    profile = performance_profile({"a": np.array([0.0, 2.0]), "b": np.ones(8)}, np.array([-1.0, 0.5, 1.5, 3.0]))
    assert profile.tolist() == [1.0, 0.75, 0.25, 0.0]


def test_the_report_compares_methods_across_the_tasks_they_ran(tmp_path):
    returns = np.full(20, -200.0)
    for seed in range(3):
        for env, threshold, solved in (("MountainCar-v0", -110.0, -100.0), ("Acrobot-v1", -100.0, -90.0)):
            write_run(
                tmp_path / "runs" / env / f"good{seed}",
                "dqn+gaussian",
                seed,
                returns,
                env=env,
                threshold=threshold,
                final_eval=solved,
            )
            write_run(
                tmp_path / "runs" / env / f"poor{seed}",
                "dqn+egreedy",
                seed,
                returns,
                env=env,
                threshold=threshold,
                final_eval=-200.0,
            )
    runs = load_runs(tmp_path / "runs")
    scores = normalized_scores(runs)
    assert scores["dqn+egreedy"]["Acrobot-v1"].tolist() == [0.0] * 3  # the lowest return of the task
    assert scores["dqn+gaussian"]["MountainCar-v0"] == pytest.approx([100 / 90] * 3)  # above the threshold
    fractions = budget_fractions([run.summary for run in runs])
    assert fractions["dqn+egreedy"]["MountainCar-v0"].tolist() == [1.0] * 3  # never solved
    main([str(tmp_path / "runs"), "--out", str(tmp_path / "report")])
    markdown = (tmp_path / "report" / "results.md").read_text()
    section = markdown.split("## Across tasks")[1]
    assert "| dqn+gaussian | Acrobot-v1, MountainCar-v0 | 6 | 1.11 [1.11, 1.11] |" in section
    assert (tmp_path / "report" / "across_tasks_profiles.png").exists()
