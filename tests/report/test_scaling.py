from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from test_report import assert_png, table_row, write_run

from torchrl_mbe.report import load_runs, main, write_report


def write_deepsea_run(
    run_dir: Path,
    method: str,
    size: int,
    seed: int,
    *,
    solved_after: int | None,
    first_treasure: int | None,
    experiment: dict | None = None,
) -> Path:
    """A 50-episode DeepSea-``size`` run, solved once ``solved_after`` episodes had finished, that
    reaches the treasure from episode ``first_treasure`` on (``None``: never); ``experiment``: more summary fields."""
    returns = np.full(50, -1.0)
    if first_treasure is not None:
        returns[first_treasure - 1 :] = 0.99
    # write_run ends episode i at 200 * i frames: solved between the ends of episodes solved_after and solved_after + 1
    solved_at = None if solved_after is None else 200 * solved_after + 1
    write_run(
        run_dir,
        method,
        seed,
        returns,
        env=f"DeepSea-{size}",
        threshold=0.5,
        experiment={"solved": solved_after is not None, "solved_at_frames": solved_at, **(experiment or {})},
    )
    episodes = run_dir / "episodes.csv"  # write_run flags the goal on MountainCar only: flag the treasure here
    header, *rows = episodes.read_text().splitlines()
    cells = [row.split(",") for row in rows]
    for row, found in zip(cells, returns > 0):
        row[header.split(",").index("reached_goal")] = str(int(found))
    episodes.write_text("\n".join([header, *(",".join(row) for row in cells)]) + "\n")
    return run_dir


@pytest.fixture
def scaling_dir(tmp_path: Path) -> Path:
    """dqn+gaussian solves N = 10, 20 on both seeds and N = 30 on one; dqn+egreedy solves N = 10 on one seed only."""
    root = tmp_path / "runs"
    outcomes = {  # (method, N): per seed (episodes to solved, first treasure episode)
        ("dqn+gaussian", 10): [(10, 4), (20, 6)],
        ("dqn+gaussian", 20): [(30, 12), (40, 20)],
        ("dqn+gaussian", 30): [(45, 30), (None, 41)],
        ("dqn+egreedy", 10): [(25, 9), (None, None)],
        ("dqn+egreedy", 20): [(None, None), (None, None)],
        ("dqn+egreedy", 30): [(None, None), (None, None)],
    }
    for (method, size), seeds in outcomes.items():
        for seed, (solved_after, first_treasure) in enumerate(seeds):
            write_deepsea_run(
                root / method / str(size) / str(seed),
                method,
                size,
                seed,
                solved_after=solved_after,
                first_treasure=first_treasure,
            )
    return root


def test_episodes_to_solved_counts_the_episodes_finished_by_the_solved_evaluation(scaling_dir):
    runs = {(r.method, r.env, r.seed): r for r in load_runs(scaling_dir)}
    assert runs["dqn+gaussian", "DeepSea-20", 1].episodes_to_solved == 40
    assert runs["dqn+gaussian", "DeepSea-30", 1].episodes_to_solved is None


def test_scaling_tables_and_figure(scaling_dir, tmp_path):
    main([str(scaling_dir), "--out", str(tmp_path / "out")])
    results = (tmp_path / "out" / "results.md").read_text()
    scaling = results.split("## DeepSea: scaling with size N\n", 1)[1]
    assert "| method | N = 10 | N = 20 | N = 30 |" in scaling
    assert table_row(scaling, "### Episodes to solved", "dqn+gaussian")[1:] == [
        "2/2, 15 [10, 20]",
        "2/2, 35 [30, 40]",
        "1/2, 45 [45, 45]",
    ]
    assert table_row(scaling, "### Episodes to solved", "dqn+egreedy")[1:] == ["1/2, 25 [25, 25]", "0/2", "0/2"]
    first_treasure = "### Episodes to the first treasure"
    assert table_row(scaling, first_treasure, "dqn+gaussian")[1:] == [
        "2/2, 5 [4, 6]",
        "2/2, 16 [12, 20]",
        "2/2, 36 [30, 41]",
    ]
    assert table_row(scaling, first_treasure, "dqn+egreedy")[1:] == ["1/2, 9 [9, 9]", "0/2", "0/2"]
    assert "![episodes to solved against N](scaling_DeepSea.png)" in scaling
    assert_png(tmp_path / "out" / "scaling_DeepSea.png")
    for size in (10, 20, 30):  # the per-size sections stay
        assert (
            f"## DeepSea-{size}\n" in results and (tmp_path / "out" / f"learning_curves_DeepSea-{size}.png").is_file()
        )


def test_size_not_run_by_a_method_is_a_dash(scaling_dir, tmp_path):
    write_deepsea_run(scaling_dir / "noisy", "dqn+noisy", 20, 0, solved_after=5, first_treasure=2)
    write_report(load_runs(scaling_dir), tmp_path / "out")
    results = (tmp_path / "out" / "results.md").read_text()
    assert table_row(results, "### Episodes to solved", "dqn+noisy")[1:] == ["–", "1/1, 5 [5, 5]", "–"]


def test_deepsea_at_one_size_has_no_scaling_section(tmp_path):
    for seed in (0, 1):
        write_deepsea_run(tmp_path / "runs" / str(seed), "dqn+gaussian", 10, seed, solved_after=10, first_treasure=3)
    written = write_report(load_runs(tmp_path / "runs"), tmp_path / "out")
    assert "scaling" not in (tmp_path / "out" / "results.md").read_text()
    assert "scaling_DeepSea.png" not in {path.name for path in written}


def test_growth_is_the_loglog_slope_over_the_sizes_half_the_seeds_solved(tmp_path):
    """Medians 4, 16, 36 at N = 10, 20, 30 grow as N^2; N = 40, solved early by one seed of three, stays out of the fit.
    Every seed finds the treasure, at episode N / 5: that grows as N^1 over all four sizes."""
    outcomes = {10: [4, 4], 20: [16, 16], 30: [36, None], 40: [2, None, None]}
    for size, seeds in outcomes.items():
        for seed, solved_after in enumerate(seeds):
            write_deepsea_run(
                tmp_path / "runs" / str(size) / str(seed),
                "dqn+diagonal",
                size,
                seed,
                solved_after=solved_after,
                first_treasure=size // 5,
            )
    write_deepsea_run(tmp_path / "runs" / "egreedy", "dqn+egreedy", 10, 0, solved_after=25, first_treasure=9)
    main([str(tmp_path / "runs"), "--out", str(tmp_path / "out")])
    results = (tmp_path / "out" / "results.md").read_text()
    assert table_row(results, "### Growth with N", "dqn+diagonal")[1:] == [
        "2.00",
        "10, 20, 30",
        "1.00",
        "10, 20, 30, 40",
    ]
    assert table_row(results, "### Growth with N", "dqn+egreedy")[1:] == ["–", "–", "–", "–"]


def test_equal_medians_at_every_size_grow_as_n_to_the_zero_not_minus_zero(tmp_path):
    """The categorical preset solves N=10 and N=20 in a median of 400 episodes each: a flat line reads 0.00."""
    for size in (10, 20):
        write_deepsea_run(tmp_path / "runs" / str(size), "dqn+diagonal", size, 0, solved_after=40, first_treasure=7)
    main([str(tmp_path / "runs"), "--out", str(tmp_path / "out")])
    results = (tmp_path / "out" / "results.md").read_text()
    assert table_row(results, "### Growth with N", "dqn+diagonal")[1:] == ["0.00", "10, 20", "0.00", "10, 20"]


def test_a_method_run_with_two_presets_draws_one_series_per_preset(tmp_path):
    """Each size has its own config_id; the preset's tag, not the config, joins a series across sizes."""
    for tag, episodes in (("deepsea_learned", {10: 20, 20: 40}), ("deepsea_categorical", {10: 10, 20: 15})):
        for size, solved_after in episodes.items():
            write_deepsea_run(
                tmp_path / "runs" / tag / str(size),
                "dqn+diagonal",
                size,
                0,
                solved_after=solved_after,
                first_treasure=1,
                experiment={"tag": tag, "config_id": f"{tag}-{size}"},
            )
    main([str(tmp_path / "runs"), "--out", str(tmp_path / "out")])
    results = (tmp_path / "out" / "results.md").read_text()
    assert table_row(results, "### Episodes to solved", "dqn+diagonal [deepsea_learned]")[1:] == [
        "1/1, 20 [20, 20]",
        "1/1, 40 [40, 40]",
    ]
    assert table_row(results, "### Episodes to solved", "dqn+diagonal [deepsea_categorical]")[1:] == [
        "1/1, 10 [10, 10]",
        "1/1, 15 [15, 15]",
    ]
