"""``hydra/launcher=population``: a sweep's jobs that differ only in ``seed`` run as populations."""

from __future__ import annotations

import json

import pytest

from torchrl_mbe.app.sweeps import group_seeds, trains_together


def test_jobs_that_set_population_or_no_seed_or_differ_elsewhere_stay_as_they_are():
    jobs = [
        ["seed=0", "population=2"],
        ["seed=2", "population=2"],  # populations already
        ["exploration=kernel"],  # no seed of its own
        ["seed=3", "algo.lr=0.1"],
        ["seed=4", "algo.lr=0.2"],  # differ in more than the seed
        ["seed=5", "seed=6"],
        ["seed=random"],  # no one integer seed
    ]
    assert group_seeds(jobs, can_group=lambda overrides: True) == jobs


def test_seeds_are_grouped_in_runs_of_consecutive_seeds_whatever_order_the_sweep_lists_them():
    jobs = [["env=acrobot", f"seed={seed}"] for seed in (4, 0, 2, 1, 3, 9, 8, 9)]
    asked = []
    grouped = group_seeds(jobs, can_group=lambda overrides: asked.append(overrides) or True)
    assert grouped == [
        ["env=acrobot", "seed=0", "population=5"],
        ["env=acrobot", "seed=8", "population=2"],
        ["env=acrobot", "seed=9"],
    ]
    assert asked == grouped[:2]  # every population job was checked before it was made; the repeated seed runs alone


@pytest.mark.parametrize(
    ("overrides", "together"),
    [
        (("exploration=gaussian",), True),
        (("exploration=egreedy",), True),
        (("exploration=rnd",), True),
        (("buffer=prioritized",), False),
    ],
)
def test_a_config_trains_together_when_its_population_passes_the_checks(overrides, together, compose_config):
    assert trains_together(compose_config(*overrides, "population=3")) is together


def test_a_seed_sweep_through_the_population_launcher_writes_each_seeds_run_as_a_single_sweep_would(tmp_path, run_app):
    sweep = tmp_path / "sweep"
    result = run_app(
        "-m",
        "buffer=uniform,prioritized",
        "seed=0,1",
        "hydra/launcher=population",
        f"hydra.sweep.dir={sweep}",
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stderr
    assert "hydra/launcher=population: 4 runs as 3 jobs" in result.stdout + result.stderr
    summaries = {
        path.relative_to(sweep).as_posix(): json.loads(path.read_text()) for path in sweep.glob("**/summary.json")
    }
    runs = sorted((name, summary["seed"]) for name, summary in summaries.items())
    assert runs == [
        ("0/seed0/summary.json", 0),  # one process, population=2
        ("0/seed1/summary.json", 1),
        ("1/summary.json", 0),  # a prioritized buffer trains one agent per process
        ("2/summary.json", 1),
    ]
    assert "population=2" in (sweep / "0" / ".hydra" / "overrides.yaml").read_text()
    assert "buffer=prioritized" in (sweep / "1" / ".hydra" / "overrides.yaml").read_text()


def test_the_study_sweeps_every_explorer_over_seeds_0_to_4_through_the_population_launcher(tmp_path, run_app):
    result = run_app("--cfg", "hydra", "experiment=study", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "population_launcher.PopulationLauncher" in result.stdout
    assert (
        "exploration: gaussian,kernel,diagonal,knn,kde,rnd,noisy,egreedy" in result.stdout
        and "seed: 0,1,2,3,4" in result.stdout
    )
