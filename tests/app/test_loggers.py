"""The run's loggers as a user reads them: TensorBoard's scalars match the CSV tables."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from torchrl_mbe.app import ConfigError, train
from torchrl_mbe.app.loggers import TENSORBOARD_DIR, RunLogger


def tensorboard_scalars(run_dir: Path) -> dict[str, list[tuple[int, float]]]:
    """Every scalar of the run's event files as TensorBoard shows it: ``tag -> [(step, value), ...]``."""
    events = EventAccumulator(str(run_dir / TENSORBOARD_DIR), size_guidance={"scalars": 0})
    events.Reload()
    return {tag: [(event.step, event.value) for event in events.Scalars(tag)] for tag in events.Tags()["scalars"]}


def column(rows: list[dict], name: str) -> list[tuple[int, float]]:
    return [(int(row["frames"]), pytest.approx(float(row[name]), rel=1e-6)) for row in rows if row[name] != ""]


def test_logger_tensorboard_writes_the_tables_scalars_at_their_frames(tmp_path, compose_config, read_table):
    overrides = ("logger=tensorboard", "logger.log_every_updates=10", "eval.every_frames=160", "eval.episodes=2")
    train(compose_config(*overrides), tmp_path)
    scalars = tensorboard_scalars(tmp_path)
    episodes, evaluations, updates = (read_table(tmp_path, table) for table in ("episodes", "evaluations", "updates"))
    assert episodes and evaluations and updates
    for table, rows, name in [
        ("episodes", episodes, "return"),
        ("episodes", episodes, "length"),
        ("episodes", episodes, "eps"),
        ("evaluations", evaluations, "eval_return_mean"),
        ("updates", updates, "loss_q"),
        ("updates", updates, "eps"),
        ("updates", updates, "frames_per_s"),
    ]:
        assert scalars[f"{table}/{name}"] == column(rows, name), f"{table}/{name}"


def test_a_resumed_run_hides_the_scalars_logged_after_its_checkpoint(tmp_path, compose_config):
    cfg = compose_config("logger=tensorboard")
    first = RunLogger(tmp_path, cfg)
    for frames, loss in [(100, 1.0), (200, 2.0), (300, 3.0)]:
        first.log("updates", {"frames": frames, "loss_q": loss})
    first.close()  # killed after frame 300, its checkpoint at frame 200
    resumed = RunLogger(tmp_path, cfg, resume_frames=200)
    resumed.log("updates", {"frames": 300, "loss_q": 30.0})
    resumed.close()
    assert tensorboard_scalars(tmp_path)["updates/loss_q"] == [(100, 1.0), (200, 2.0), (300, 30.0)]


def test_logger_tensorboard_without_the_package_names_what_to_install_before_the_run_starts(
    tmp_path, compose_config, monkeypatch
):
    monkeypatch.setitem(sys.modules, "tensorboard", None)  # import tensorboard now fails, as where it is not installed
    with pytest.raises(
        ConfigError,
        match=r'^logger=tensorboard: the tensorboard package is not installed; pip install "torchrl-mbe\[tensorboard\]"',
    ):
        train(compose_config("logger=tensorboard"), tmp_path)
    assert not any(tmp_path.iterdir())
