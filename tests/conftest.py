"""Shared setup: one torch thread, a fixed seed, wandb off; the app tests' config and subprocess helpers."""

from __future__ import annotations

import csv
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir

from torchrl_mbe.app import register_configs

os.environ.setdefault("WANDB_MODE", "disabled")
torch.set_num_threads(1)  # tiny networks: one thread is fastest and immune to a busy machine
register_configs()  # the fixtures compose conf/, which extends the schema


@pytest.fixture(autouse=True)
def _seed_and_threads():
    torch.manual_seed(0)
    yield


REPO = Path(__file__).resolve().parents[1]
QUICK = (
    "logger=csv",
    "progress_bar=false",
    "train.episodes=50",
    "train.max_frames=300",
    "algo.learning_starts=100",
    "eval.episodes=0",
    "eval.final_episodes=1",
    "env.num_envs=1",
    "collector.frames_per_batch=16",
    "train.stop_when_solved=false",
    "processes=1",
)
"""A few hundred frames on one env, 16 frames per batch, one process: every part runs, nothing is learned."""


@pytest.fixture
def compose_config():
    """``compose_config(*overrides)``: the app's config with :data:`QUICK` and ``overrides`` applied."""

    def compose_with(*overrides: str):
        with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
            return compose("config", overrides=[*quick_for(overrides), *overrides])

    return compose_with


@pytest.fixture
def compose_default():
    """``compose_default(*overrides)``: the app's config as ``python train.py`` composes it (CSV logging, no bar)."""

    def compose_with(*overrides: str):
        with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
            return compose("config", overrides=["logger=csv", "progress_bar=false", *overrides])

    return compose_with


def quick_for(overrides) -> list[str]:
    """:data:`QUICK`, less the keys ``overrides`` set themselves and its DQN settings when they pick REINFORCE."""
    named = {override.split("=", 1)[0] for override in overrides}
    return [
        o
        for o in QUICK
        if o.split("=", 1)[0] not in named and not ("algo=reinforce" in overrides and o.startswith("algo."))
    ]


@pytest.fixture
def run_app():
    """``run_app(*args, cwd=...)``: ``python train.py`` with :data:`QUICK` and ``args`` in a subprocess."""

    def run(*args: str, cwd: Path, env: dict | None = None) -> subprocess.CompletedProcess:
        """``env``: variables to set on top of this process's; a value of ``None`` unsets one."""
        return subprocess.run(
            [sys.executable, str(REPO / "train.py"), *args, *quick_for(args)],
            cwd=cwd,
            env=_environment({"WANDB_MODE": "disabled", **(env or {})}),
            capture_output=True,
            text=True,
            timeout=600,
        )

    return run


@pytest.fixture
def read_table():
    """``read_table(run_dir, table)``: the rows of one of a run's CSV tables."""

    def read(run_dir: Path, table: str) -> list[dict]:
        with (run_dir / f"{table}.csv").open() as handle:
            return list(csv.DictReader(handle))

    return read


def _environment(changes: dict) -> dict:
    environment = {**os.environ, **changes}
    return {key: value for key, value in environment.items() if value is not None}
