from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from matplotlib.image import imread

from torchrl_mbe.envs.registry import TASKS
from torchrl_mbe.report import load_runs, main
from torchrl_mbe.report.figures import last_finished_episode, mean_curve
from torchrl_mbe.report.runs import group_runs

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
MOUNTAINCAR = TASKS["mountaincar"].bounds


def write_run(
    run_dir: Path,
    method: str,
    seed: int,
    returns: np.ndarray,
    *,
    env: str = "MountainCar-v0",
    threshold: float | None = -110.0,
    final_eval: float | None = None,
    evaluations: list[float] | None = None,
    states: np.ndarray | None = None,
    experiment: dict | None = None,
) -> Path:
    """A run directory in the training app's format."""
    run_dir.mkdir(parents=True)
    reached = returns > -200 if env == "MountainCar-v0" else np.zeros(len(returns), dtype=bool)
    lengths = np.where(reached, -returns, 200).astype(int)
    frames = np.cumsum(lengths)
    summary = {
        "env": env,
        "method": method,
        "seed": seed,
        "frames": int(frames[-1]),
        "episodes": len(returns),
        "wall_time_s": 12.5,
        "final_eval_return": final_eval,
        "solved_threshold": threshold,
        **(experiment or {}),
    }
    (run_dir / "summary.json").write_text(json.dumps(summary))
    rows = ["episode,frames,return,length,reached_goal,eps,wall_time_s"]
    rows += [
        f"{i + 1},{frames[i]},{returns[i]},{lengths[i]},{int(reached[i])},0.5,{0.1 * i:.1f}"
        for i in range(len(returns))
    ]
    (run_dir / "episodes.csv").write_text("\n".join(rows) + "\n")
    if evaluations is not None:
        lines = ["frames,episode,eval_return_mean,eval_return_std,eval_success_rate"]
        lines += [f"{1000 * (i + 1)},{10 * (i + 1)},{value},5.0,0.5" for i, value in enumerate(evaluations)]
        (run_dir / "evaluations.csv").write_text("\n".join(lines) + "\n")
    if states is not None:
        np.save(run_dir / "visited_states.npy", states.astype(np.float32))
        episode_of_step = np.arange(len(states)) * len(returns) // len(states) + 1
        np.save(run_dir / "visited_episodes.npy", episode_of_step.astype(np.int64))
    return run_dir


def mountaincar_cells(cells: list[tuple[int, int]], repeats: int = 3) -> np.ndarray:
    """States at the centers of the given (position bin, velocity bin) cells of the 20x20 grid."""
    low, high = np.array(MOUNTAINCAR.low), np.array(MOUNTAINCAR.high)
    centers = low + (np.array(cells) + 0.5) * (high - low) / 20
    return np.repeat(centers, repeats, axis=0)


@pytest.fixture
def runs_dir(tmp_path: Path) -> Path:
    """2 learning methods x 2 seeds and 2 exploration methods x 2 seeds on MountainCar, one LunarLander
    exploration run; nested like Hydra multirun sweeps."""
    root = tmp_path / "runs"
    sweep = root / "multirun" / "2025-01-01" / "12-00-00"

    def failures_then_goal(first_success: int) -> np.ndarray:  # 150 episodes
        return np.r_[np.full(first_success - 1, -200.0), np.full(151 - first_success, -100.0)]

    write_run(sweep / "0", "dqn+gaussian", 0, failures_then_goal(10), final_eval=-105.0)
    write_run(sweep / "1", "dqn+gaussian", 1, failures_then_goal(30), evaluations=[-150.0, -98.0])
    write_run(sweep / "2", "dqn+egreedy", 0, np.full(80, -200.0), evaluations=[])
    write_run(sweep / "3", "dqn+egreedy", 1, np.full(80, -200.0))
    (sweep / "2" / "evaluations.csv").write_text("")  # empty evaluations count as none

    explore = root / "explore"
    goal_in_3_and_5 = np.array([-200.0, -200.0, -150.0, -200.0, -120.0])
    no_goal = np.full(5, -200.0)
    every_cell = [(p, v) for p in range(20) for v in range(20)]
    write_run(explore / "gaussian" / "0", "explore:gaussian", 0, goal_in_3_and_5, states=mountaincar_cells(every_cell))
    write_run(explore / "gaussian" / "1", "explore:gaussian", 1, no_goal, states=mountaincar_cells(every_cell[:40]))
    four_cells, eight_cells = [(7, 9), (7, 10), (8, 9), (8, 10)], [(7, v) for v in range(6, 14)]
    write_run(explore / "random" / "0", "explore:random", 0, no_goal, states=mountaincar_cells(four_cells))
    write_run(explore / "random" / "deeper" / "1", "explore:random", 1, no_goal, states=mountaincar_cells(eight_cells))

    lunar_states = np.random.default_rng(0).normal(0.0, 0.5, size=(500, 8))
    lunar_states[:, 6:] = lunar_states[:, 6:] > 0
    write_run(
        root / "lunar",
        "explore:random",
        0,
        np.full(5, -150.0),
        env="LunarLander-v3",
        threshold=200.0,
        states=lunar_states,
    )
    return root


def table_row(markdown: str, section: str, method: str) -> list[str]:
    """The cells of ``method``'s row in the first table after the heading ``section``."""
    after = markdown.split(section, 1)[1]
    for line in after.splitlines():
        if line.startswith(f"| {method} |"):
            return [cell.strip() for cell in line.strip("|").split("|")]
    raise AssertionError(f"no row for {method} after {section}")


def env_section(markdown: str, env: str) -> str:
    """The part of results.md under ``## env``."""
    return markdown.split(f"## {env}\n", 1)[1].split("\n## ", 1)[0]


def assert_png(path: Path) -> np.ndarray:
    assert path.read_bytes()[:8] == PNG_SIGNATURE
    image = imread(path)
    assert image.shape[0] > 200 and image.shape[1] > 200
    assert image[..., :3].std() > 0.05  # not a blank canvas
    return image


class TestReport:
    def test_writes_figures_and_tables_and_prints_their_paths(self, runs_dir, capsys):
        main([str(runs_dir)])
        out = runs_dir / "report"
        names = {
            "learning_curves_MountainCar-v0.png",
            "greedy_evaluations_MountainCar-v0.png",
            "coverage_MountainCar-v0.png",
            "coverage_LunarLander-v3.png",
            "results.md",
        }
        assert {p.name for p in out.iterdir()} == names
        assert sorted(capsys.readouterr().out.split()) == sorted(str(out / name) for name in names)
        for name in names - {"results.md"}:
            assert_png(out / name)
        # two panels side by side (MountainCar) vs. one (LunarLander)
        assert (
            imread(out / "coverage_MountainCar-v0.png").shape[1] > imread(out / "coverage_LunarLander-v3.png").shape[1]
        )

    def test_learning_table_numbers(self, runs_dir, tmp_path):
        main([str(runs_dir), "--out", str(tmp_path / "out")])
        results = (tmp_path / "out" / "results.md").read_text()
        gaussian = table_row(results, "### Learning", "dqn+gaussian")
        assert gaussian[1:] == [
            "0, 1",
            "150.0 [150, 150]",
            "20.0 [10, 30]",  # first success episodes
            "131.0 [141, 121]",  # successful episodes
            "-100.0 [-100.0, -100.0]",
            "-100.0 [-100.0, -100.0]",
            "-101.5 [-105.0, -98.0]",  # summary's final eval; last evaluations.csv row when it is null
            "2/2 at [100, 119]",
        ]
        egreedy = table_row(results, "### Learning", "dqn+egreedy")
        assert egreedy[3:5] == ["– [–, –]", "0.0 [0, 0]"]
        assert egreedy[5] == "-200.0 [-200.0, -200.0]"  # 80-episode runs: their average over all episodes
        assert egreedy[7:] == ["– [–, –]", "0/2 at [–, –]"]
        assert "solved at a 100-episode average of -110" in results

    def test_exploration_table_numbers(self, runs_dir, tmp_path):
        main([str(runs_dir), "--out", str(tmp_path / "out")])
        results = (tmp_path / "out" / "results.md").read_text()
        mountaincar = env_section(results, "MountainCar-v0")
        gaussian = table_row(mountaincar, "### Exploration", "explore:gaussian")
        assert gaussian[1:] == [
            "0, 1",
            "5.0 [5, 5]",
            "1.0 [2, 0]",  # episodes reaching the goal
            "3.0 [3, –]",  # first success
            "55.0% ± 45.0% [100.0%, 10.0%]",  # coverage of the 20x20 position x velocity grid
            "-0.255 [0.555, -1.065]",  # max position
        ]
        random = table_row(mountaincar, "### Exploration", "explore:random")
        assert random[5] == "1.5% ± 0.5% [1.0%, 2.0%]"
        assert "explore:gaussian seed 0 (100.0%), explore:random seed 1 (2.0%)" in mountaincar  # method_key order
        lunarlander = env_section(results, "LunarLander-v3")
        assert "coverage x-velocity x y-velocity | coverage, mean over pairs of 6 dims" in lunarlander
        assert "max position" not in lunarlander and "### Learning" not in lunarlander

    def test_window_and_bins_options(self, runs_dir, tmp_path):
        main([str(runs_dir), "--out", str(tmp_path / "out"), "--window", "10", "--bins", "10"])
        results = (tmp_path / "out" / "results.md").read_text()
        # a 10-episode window averages >= -110 once it holds at most one -200 failure
        assert table_row(results, "### Learning", "dqn+gaussian")[8] == "2/2 at [18, 38]"
        # on a 10x10 grid both random runs fall into 4 cells
        random = table_row(env_section(results, "MountainCar-v0"), "### Exploration", "explore:random")
        assert random[5] == "4.0% ± 0.0% [4.0%, 4.0%]"

    def test_env_without_threshold_or_bounds(self, tmp_path):
        states = np.random.default_rng(0).uniform(-3.0, 3.0, size=(400, 3))
        write_run(tmp_path / "runs" / "a", "dqn+gaussian", 0, np.full(120, 1.0), env="Custom-v0", threshold=None)
        write_run(
            tmp_path / "runs" / "b",
            "explore:random",
            0,
            np.full(4, 1.0),
            env="Custom-v0",
            threshold=None,
            states=states,
        )
        main([str(tmp_path / "runs")])
        results = (tmp_path / "runs" / "report" / "results.md").read_text()
        assert "### Learning (no solved threshold)" in results
        assert table_row(results, "### Learning", "dqn+gaussian")[8] == "0/1 at [–]"
        assert "fitted to this environment's visited states" in results
        assert_png(tmp_path / "runs" / "report" / "learning_curves_Custom-v0.png")
        assert_png(tmp_path / "runs" / "report" / "coverage_Custom-v0.png")

    def test_runs_found_at_any_depth(self, runs_dir):
        runs = load_runs(runs_dir)
        assert len(runs) == 9
        assert sum(run.is_exploration for run in runs) == 5


class TestGrouping:
    def test_runs_of_different_configs_never_merge_and_labels_count_distinct_seeds(self, tmp_path):
        returns = np.full(5, -200.0)
        for seed in (0, 1):
            write_run(
                tmp_path / f"a{seed}", "dqn+gaussian", seed, returns, experiment={"tag": "default", "config_id": "aaaa"}
            )
        write_run(tmp_path / "b0", "dqn+gaussian", 0, returns, experiment={"tag": "sweep", "config_id": "bbbb"})
        groups = group_runs(load_runs(tmp_path))
        assert {label: [r.seed for r in runs] for label, runs in groups.items()} == {
            "dqn+gaussian [default aaaa]": [0, 1],
            "dqn+gaussian [sweep bbbb]": [0],
        }

    def test_one_method_with_a_config_per_env_reports_every_env(self, tmp_path):
        for env, config_id in (("MountainCar-v0", "aaaa"), ("CartPole-v1", "bbbb")):
            write_run(
                tmp_path / env,
                "dqn+gaussian",
                0,
                np.full(5, -200.0),
                env=env,
                evaluations=[-200.0],
                experiment={"tag": "default", "config_id": config_id},
            )
        main([str(tmp_path), "--out", str(tmp_path / "report")])
        results = (tmp_path / "report" / "results.md").read_text()
        for env in ("MountainCar-v0", "CartPole-v1"):
            assert table_row(env_section(results, env), "### Greedy evaluations", "dqn+gaussian")[1] == "0"

    def test_curves_of_unequal_length_are_averaged_over_the_runs_still_going(self):
        mean, low, high = mean_curve([np.array([1.0, 2.0, 3.0]), np.array([5.0])])
        assert mean.tolist() == [3.0, 2.0, 3.0] and low.tolist() == [1.0, 2.0, 3.0] and high.tolist() == [5.0, 2.0, 3.0]

    def test_greedy_table_counts_solved_seeds_and_time_to_solved(self, tmp_path):
        returns = np.full(5, -150.0)
        outcomes = [(-105.0, True, 30000, 60.0), (-120.0, False, None, None)]
        for seed, (final, solved, frames, seconds) in enumerate(outcomes):
            write_run(
                tmp_path / f"s{seed}",
                "dqn+gaussian",
                seed,
                returns,
                final_eval=final,
                experiment={
                    "solved": solved,
                    "best_eval_return": -104.0,
                    "solved_at_frames": frames,
                    "solved_at_wall_time_s": seconds,
                },
            )
        main([str(tmp_path), "--out", str(tmp_path / "report")])
        row = table_row((tmp_path / "report" / "results.md").read_text(), "### Greedy evaluations", "dqn+gaussian")
        assert row[2:6] == ["1/2", "-112.5 [-105.0, -120.0]", "-104.0 [-104.0, -104.0]", "30000 [30000, –]"]

    def test_summary_gives_medians_over_the_seeds_that_solved_and_a_frames_to_solved_figure(self, tmp_path):
        returns = np.r_[np.full(3, -200.0), np.full(3, -100.0)]  # first success: episode 4
        outcomes = [(True, 20000, 40.0, 500.0), (True, 60000, 100.0, 300.0), (False, None, None, 400.0)]
        cells = [[(0, 0), (1, 1)], [(0, 0), (1, 1), (2, 2), (3, 3)], None]  # 6 and 12 visited states, none
        for seed, (solved, frames, seconds, fps) in enumerate(outcomes):
            states = None if cells[seed] is None else mountaincar_cells(cells[seed])
            write_run(
                tmp_path / f"s{seed}",
                "dqn+knn",
                seed,
                returns,
                final_eval=-100.0 - 10 * seed,
                states=states,
                experiment={
                    "solved": solved,
                    "solved_at_frames": frames,
                    "solved_at_wall_time_s": seconds,
                    "frames_per_s": fps,
                },
            )
        main([str(tmp_path), "--out", str(tmp_path / "report")])
        markdown = (tmp_path / "report" / "results.md").read_text()
        assert "coverage of the first 6 frames" in markdown.split("### Summary", 1)[1].split("\n\n")[1]
        row = table_row(markdown, "### Summary", "dqn+knn")
        assert row[1:] == ["2/3", "40000", "70", "4", "-110.0", "0.5%", "400"]  # 2 of 400 cells in each run's first 6
        assert_png(tmp_path / "report" / "frames_to_solved_MountainCar-v0.png")

    def test_coverage_figure_wraps_many_methods_into_rows(self, tmp_path):
        for count in (4, 5):
            for index in range(count):
                write_run(
                    tmp_path / f"m{count}" / str(index),
                    f"dqn+m{index}",
                    0,
                    np.full(4, -200.0),
                    states=mountaincar_cells([(index, index)]),
                )
            main([str(tmp_path / f"m{count}"), "--out", str(tmp_path / f"report{count}")])
        one_row = assert_png(tmp_path / "report4" / "coverage_MountainCar-v0.png")
        two_rows = assert_png(tmp_path / "report5" / "coverage_MountainCar-v0.png")
        assert two_rows.shape[1] == one_row.shape[1] and two_rows.shape[0] > 1.8 * one_row.shape[0]

    def test_coverage_colour_bar_ends_at_the_last_finished_episode(self, tmp_path):
        run_dir = write_run(
            tmp_path / "r", "explore:gaussian", 0, np.full(4, -200.0), states=mountaincar_cells([(1, 1)] * 5)
        )
        episodes = np.load(run_dir / "visited_episodes.npy")
        np.save(
            run_dir / "visited_episodes.npy", np.append(episodes[:-1], 5)
        )  # the last state: an unfinished 5th episode
        assert last_finished_episode(load_runs(tmp_path)) == 4


class TestErrors:
    def run_main(self, *args: str) -> str:
        with pytest.raises(SystemExit) as excinfo:
            main(list(args))
        message = excinfo.value.code
        assert isinstance(message, str) and "\n" not in message
        return message

    def test_missing_dir(self, tmp_path):
        assert "does not exist" in self.run_main(str(tmp_path / "nope"))

    def test_dir_without_runs(self, tmp_path):
        (tmp_path / "sub").mkdir()
        assert "no runs under" in self.run_main(str(tmp_path))
        assert not (tmp_path / "report").exists()

    def test_summary_not_json(self, runs_dir):
        summary = runs_dir / "multirun" / "2025-01-01" / "12-00-00" / "1" / "summary.json"
        summary.write_text('{"env": "MountainCar-v0",')
        message = self.run_main(str(runs_dir))
        assert str(summary) in message and "not valid JSON" in message

    @pytest.mark.parametrize(
        "change, expected",
        [
            ({"method": None}, "field 'method' must be a non-empty string"),
            ({"seed": "zero"}, "field 'seed' must be an integer"),
        ],
    )
    def test_summary_wrong_field(self, runs_dir, change, expected):
        summary = runs_dir / "explore" / "random" / "0" / "summary.json"
        summary.write_text(json.dumps({**json.loads(summary.read_text()), **change}))
        message = self.run_main(str(runs_dir))
        assert str(summary) in message and expected in message

    def test_summary_missing_field(self, runs_dir):
        summary = runs_dir / "explore" / "random" / "0" / "summary.json"
        data = json.loads(summary.read_text())
        del data["solved_threshold"]
        summary.write_text(json.dumps(data))
        assert "missing field 'solved_threshold'" in self.run_main(str(runs_dir))

    def test_episodes_csv_bad_value(self, runs_dir):
        episodes = runs_dir / "explore" / "random" / "0" / "episodes.csv"
        episodes.write_text(episodes.read_text().replace(",-200.0,", ",oops,", 1))
        message = self.run_main(str(runs_dir))
        assert str(episodes) in message and "'oops' is not a number" in message

    def test_episodes_csv_short_row(self, runs_dir):
        episodes = runs_dir / "explore" / "random" / "0" / "episodes.csv"
        episodes.write_text(episodes.read_text() + "6,1200\n")
        assert f"{episodes}: line 7 has no value in column 'return'" in self.run_main(str(runs_dir))

    def test_episodes_csv_not_text(self, runs_dir):
        episodes = runs_dir / "explore" / "random" / "0" / "episodes.csv"
        episodes.write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe")
        assert f"{episodes}: not a readable CSV file" in self.run_main(str(runs_dir))

    @pytest.mark.parametrize(
        "old, new, expected",
        [
            ("\n1,", "\n0,", "column 'episode' must count 1, 2, 3"),
            (",0,0.5,", ",2,0.5,", "'reached_goal' must hold only 0 or 1"),
        ],
    )
    def test_episodes_csv_bad_contents(self, runs_dir, old, new, expected):
        episodes = runs_dir / "explore" / "random" / "0" / "episodes.csv"
        episodes.write_text(episodes.read_text().replace(old, new, 1))
        assert expected in self.run_main(str(runs_dir))

    def test_episodes_csv_missing_column(self, runs_dir):
        episodes = runs_dir / "explore" / "random" / "0" / "episodes.csv"
        episodes.write_text(episodes.read_text().replace("reached_goal", "goal", 1))
        assert "lacks column(s) reached_goal" in self.run_main(str(runs_dir))

    def test_episodes_csv_missing(self, runs_dir):
        episodes = runs_dir / "explore" / "random" / "0" / "episodes.csv"
        episodes.unlink()
        assert f"{episodes}: missing" in self.run_main(str(runs_dir))

    def test_visited_episodes_length_mismatch(self, runs_dir):
        path = runs_dir / "explore" / "random" / "0" / "visited_episodes.npy"
        np.save(path, np.ones(3, dtype=np.int64))
        message = self.run_main(str(runs_dir))
        assert str(path) in message and "to match visited_states.npy" in message

    @pytest.mark.parametrize("option", ["--window", "--bins"])
    def test_non_positive_option(self, runs_dir, option, capsys):
        with pytest.raises(SystemExit):
            main([str(runs_dir), option, "0"])
        assert f"argument {option}: '0' is not a positive integer" in capsys.readouterr().err

    def test_cli_prints_one_line_without_traceback(self, tmp_path):
        result = subprocess.run(
            [sys.executable, "-m", "torchrl_mbe.report", str(tmp_path / "nope")],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert result.returncode == 1
        expected = f"torchrl-mbe-report: error: runs directory {tmp_path / 'nope'} does not exist."
        assert result.stderr.strip().splitlines() == [expected]
