"""Run logging: the run directory's CSV tables (always), mirrored to Weights & Biases or TensorBoard when asked."""

from __future__ import annotations

import csv
import importlib.util
import os
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from omegaconf import DictConfig, OmegaConf
from torchrl.record.loggers import Logger, TensorboardLogger, WandbLogger

from torchrl_mbe.app.explorers import logged_columns
from torchrl_mbe.rundir import table_file, tables

if TYPE_CHECKING:
    from torch.utils.tensorboard import SummaryWriter

__all__ = ["BACKENDS", "TENSORBOARD_DIR", "RunLogger", "backend_unavailable"]

BACKENDS = ("csv", "wandb", "tensorboard", "none")
"""The ``logger=`` choices: the CSV tables are always written; ``wandb`` and ``tensorboard`` mirror them."""

TENSORBOARD_DIR = "tensorboard"
"""The run directory's folder of TensorBoard event files (``tensorboard --logdir <run_dir>/tensorboard``)."""


class RunLogger:
    """Appends rows to the run's CSV tables (:func:`~torchrl_mbe.rundir.tables`, with the registered explorers' columns) and mirrors them to wandb or TensorBoard.

    Headers are written and flushed when the files open, and every row is
    flushed, so a killed run leaves readable tables. The mirror gets every
    number of a row as the scalar ``"{table}/{column}"`` (``episodes/return``,
    ``updates/loss_q``, ``updates/eps``, ...) at step ``frames``.

    wandb (``logger=wandb``) runs in ``cfg.logger.mode`` (``offline`` by default)
    unless ``WANDB_MODE`` is set in the environment, which wins; outside
    ``online`` mode it makes no network connection (``WANDB_ERROR_REPORTING=false``
    unless you set it). TensorBoard (``logger=tensorboard``, TorchRL's
    :class:`~torchrl.record.loggers.TensorboardLogger`) writes event files in
    ``<run_dir>/tensorboard`` and nothing else.

    Args:
        run_dir (Path): the run directory.
        cfg (DictConfig): the resolved run config (logged to wandb).

    Keyword Args:
        resume_frames (int, optional): when resuming, rows logged after the
            checkpoint (``frames`` above it) are dropped, since those frames are
            collected again; TensorBoard hides its scalars past that step too.
    """

    def __init__(self, run_dir: Path, cfg: DictConfig, *, resume_frames: int | None = None) -> None:
        self.run_dir = Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self._files = {}
        self._writers = {}
        for table, columns in tables(logged_columns()).items():
            path = self.run_dir / table_file(table)
            kept = _rows_up_to(path, resume_frames) if resume_frames is not None else []
            handle = path.open("w", newline="")
            writer = csv.DictWriter(handle, fieldnames=columns)
            writer.writeheader()
            writer.writerows(kept)
            handle.flush()
            self._files[table], self._writers[table] = handle, writer
        make_mirror = _MIRRORS.get(cfg.logger.backend)
        self.mirror: Logger | None = make_mirror(self.run_dir, cfg, resume_frames) if make_mirror else None

    def log(self, table: str, row: dict) -> None:
        """Appends ``row`` to ``table`` (missing columns stay empty)."""
        self._writers[table].writerow(row)
        self._files[table].flush()
        if self.mirror is not None:
            numbers = {f"{table}/{key}": value for key, value in row.items() if isinstance(value, (int, float))}
            self.mirror.log_metrics(numbers, step=int(row["frames"]))

    def close(self) -> None:
        for handle in self._files.values():
            handle.close()
        if self.mirror is not None:
            self.mirror.close()


def backend_unavailable(backend: str) -> str | None:
    """Why ``logger=backend`` cannot run here, naming what to install; ``None`` when it can."""
    if backend == "tensorboard" and importlib.util.find_spec("tensorboard") is None:
        return 'the tensorboard package is not installed; pip install "torchrl-mbe[tensorboard]" (or pip install tensorboard).'
    return None


def _rows_up_to(path: Path, frames: int) -> list[dict]:
    if not path.exists():
        return []
    with path.open(newline="") as handle:
        return [row for row in csv.DictReader(handle) if int(float(row["frames"])) <= frames]


def _make_wandb_logger(run_dir: Path, cfg: DictConfig, resume_frames: int | None) -> WandbLogger:
    mode = os.environ.get("WANDB_MODE", cfg.logger.mode)
    if mode != "online":
        # wandb 0.31 probes its telemetry host from the Python process even in offline mode
        # (its process-wide settings stay online); this switch turns that probe off.
        os.environ.setdefault("WANDB_ERROR_REPORTING", "false")
    os.environ.setdefault("WANDB_SILENT", "true")  # no run-history block on the console; the CSV tables hold it
    logger = WandbLogger(
        exp_name=run_dir.name,
        offline=False,  # TorchRL's offline=True rewrites WANDB_MODE; pass the mode instead
        save_dir=str(run_dir),
        project=cfg.logger.project,
        mode=mode,
    )
    logger.log_hparams(OmegaConf.to_container(cfg, resolve=True))
    return logger


class _ResumedTensorboardLogger(TensorboardLogger):
    """TorchRL's TensorBoard logger whose writer hides the scalars a previous attempt logged from ``purge_step`` on."""

    def __init__(self, exp_name: str, log_dir: str, *, purge_step: int | None) -> None:
        self._purge_step = purge_step
        super().__init__(exp_name=exp_name, log_dir=log_dir)

    def _create_experiment(self) -> SummaryWriter:
        from torch.utils.tensorboard import SummaryWriter  # the optional extra: imported only when asked for

        return SummaryWriter(log_dir=os.path.join(self.log_dir, self.exp_name), purge_step=self._purge_step)


def _make_tensorboard_logger(run_dir: Path, cfg: DictConfig, resume_frames: int | None) -> TensorboardLogger:
    purge_step = None if resume_frames is None else resume_frames + 1  # RunLogger keeps the rows up to resume_frames
    return _ResumedTensorboardLogger(TENSORBOARD_DIR, str(run_dir), purge_step=purge_step)


_MIRRORS: dict[str, Callable[[Path, DictConfig, int | None], Logger]] = {
    "wandb": _make_wandb_logger,
    "tensorboard": _make_tensorboard_logger,
}
