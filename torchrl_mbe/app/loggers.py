"""Run logging: the run directory's CSV tables (always), and Weights & Biases when asked."""
from __future__ import annotations

import csv
import os
from pathlib import Path

from omegaconf import DictConfig, OmegaConf
from torchrl.record.loggers import WandbLogger

from torchrl_mbe.rundir import TABLES, table_file

__all__ = ["RunLogger"]


class RunLogger:
    """Appends rows to the run's CSV tables (:data:`~torchrl_mbe.rundir.TABLES`) and mirrors them to wandb.

    Headers are written and flushed when the files open, and every row is
    flushed, so a killed run leaves readable tables. wandb (``logger=wandb``)
    runs in ``cfg.logger.mode`` (``offline`` by default) unless ``WANDB_MODE`` is
    set in the environment, which wins; outside ``online`` mode it makes no
    network connection (``WANDB_ERROR_REPORTING=false`` unless you set it).

    Args:
        run_dir (Path): the run directory.
        cfg (DictConfig): the resolved run config (logged to wandb).

    Keyword Args:
        resume_frames (int, optional): when resuming, rows logged after the
            checkpoint (``frames`` above it) are dropped, since those frames are
            collected again.
    """

    def __init__(self, run_dir: Path, cfg: DictConfig, *, resume_frames: int | None = None) -> None:
        self.run_dir = Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self._files = {}
        self._writers = {}
        for table, columns in TABLES.items():
            path = self.run_dir / table_file(table)
            kept = _rows_up_to(path, resume_frames) if resume_frames is not None else []
            handle = path.open("w", newline="")
            writer = csv.DictWriter(handle, fieldnames=columns)
            writer.writeheader()
            writer.writerows(kept)
            handle.flush()
            self._files[table], self._writers[table] = handle, writer
        self.wandb = _make_wandb_logger(self.run_dir, cfg) if cfg.logger.backend == "wandb" else None

    def log(self, table: str, row: dict) -> None:
        """Appends ``row`` to ``table`` (missing columns stay empty)."""
        self._writers[table].writerow(row)
        self._files[table].flush()
        if self.wandb is not None:
            numbers = {f"{table}/{key}": value for key, value in row.items() if isinstance(value, (int, float))}
            self.wandb.log_metrics(numbers, step=int(row["frames"]))

    def close(self) -> None:
        for handle in self._files.values():
            handle.close()
        if self.wandb is not None:
            self.wandb.experiment.finish()


def _rows_up_to(path: Path, frames: int) -> list[dict]:
    if not path.exists():
        return []
    with path.open(newline="") as handle:
        return [row for row in csv.DictReader(handle) if int(float(row["frames"])) <= frames]


def _make_wandb_logger(run_dir: Path, cfg: DictConfig) -> WandbLogger:
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
