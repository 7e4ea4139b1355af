"""A run's checkpoint files: their format version, atomic saves, weights-only loads, and the refusals in one line.

A checkpoint (``checkpoint.pt``, :data:`~torchrl_mbe.rundir.CHECKPOINT`) and a best policy
load with ``torch.load(..., weights_only=True)``: tensors and plain containers only.
"""

from __future__ import annotations

import re
from pathlib import Path

import torch
from omegaconf import DictConfig

from torchrl_mbe.app.config import ConfigError
from torchrl_mbe.app.identity import config_differences
from torchrl_mbe.rundir import CHECKPOINT

__all__ = ["CHECKPOINT_FORMAT", "load_safely", "read_checkpoint", "refuse_to_overwrite", "save_atomically"]

CHECKPOINT_FORMAT = 4
"""Version of the checkpoint layout; checkpoints of another version are refused (torchrl-mbe 0.1.0 wrote 1, 0.2.0 wrote 2, 0.3.0 wrote 3)."""


def refuse_to_overwrite(run_dir: Path) -> None:
    """One line, unless ``run_dir`` holds no checkpoint: a new run never overwrites one."""
    if (run_dir / CHECKPOINT).exists():
        raise ConfigError(
            f"{run_dir} already holds a run. Pass resume=true to continue it, "
            "or choose another directory (hydra.run.dir=... or another tag/seed)."
        )


def read_checkpoint(cfg: DictConfig, run_dir: Path) -> dict:
    """The checkpoint to resume from, refused with one line if it is missing, unreadable, or of another version or config."""
    checkpoint_path = run_dir / CHECKPOINT
    if not checkpoint_path.exists():
        raise ConfigError(f"resume=true but {checkpoint_path} does not exist: nothing to resume.")
    checkpoint = load_safely(checkpoint_path)
    if not isinstance(checkpoint, dict) or checkpoint.get("format") != CHECKPOINT_FORMAT:
        found = checkpoint.get("format", 1) if isinstance(checkpoint, dict) else "unknown"
        raise ConfigError(
            f"{checkpoint_path} has checkpoint format {found} (torchrl-mbe 0.1.0 wrote 1, 0.2.0 wrote 2, 0.3.0 wrote 3); this version "
            f"reads format {CHECKPOINT_FORMAT} only. Start a new run in another directory."
        )
    differences = config_differences(checkpoint["config"], cfg)
    if differences:
        raise ConfigError(
            f"The checkpoint in {run_dir} was made with another config; differing keys: " + "; ".join(differences)
        )
    return checkpoint


def save_atomically(state: dict, path: Path) -> None:
    """``torch.save`` through a ``.partial`` file: a crash mid-write keeps the previous file whole."""
    partial = path.with_name(path.name + ".partial")
    torch.save(state, partial)
    partial.replace(path)


def load_safely(path: Path) -> dict:
    """A checkpoint or best policy, read with ``weights_only=True``: tensors and plain containers, never code.

    Raises:
        ConfigError: one line naming the file, if it is truncated, foreign, or
            holds anything a weights-only load refuses (a pickled callable, say).

    Examples:
        >>> import tempfile, torch
        >>> from pathlib import Path
        >>> from torchrl_mbe.app.checkpoints import load_safely
        >>> path = Path(tempfile.mkdtemp()) / "policy.pt"
        >>> torch.save({"actor": {"weight": torch.zeros(2)}, "frames": 10}, path)
        >>> load_safely(path)["frames"]
        10
        >>> torch.save({"actor": print}, path)  # a callable: loading it would run code
        >>> load_safely(path)  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        torchrl_mbe.app.settings.ConfigError: Refusing .../policy.pt: it holds print, which a weights-only load does not run (only tensors and plain containers are read).
    """
    try:
        return torch.load(path, weights_only=True)
    except Exception as error:  # noqa: BLE001 (torch.load raises many types; each becomes one line naming the file)
        code = re.search(r"Unsupported global: GLOBAL (\S+)", str(error))
        if code is not None:
            raise ConfigError(
                f"Refusing {path}: it holds {code.group(1)}, which a weights-only load does not run "
                "(only tensors and plain containers are read)."
            ) from None
        raise ConfigError(f"Cannot read {path} (truncated, or not a torchrl-mbe file): {_reason(error)}") from None


def _reason(error: Exception) -> str:
    """The line of a ``torch.load`` error that says what was wrong (its messages wrap it in advice)."""
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    unpickler = next((i for i, line in enumerate(lines) if line.endswith("WeightsUnpickler error:")), None)
    if unpickler is not None and unpickler + 1 < len(lines):
        return lines[unpickler + 1]
    return lines[0].split(". ")[0] if lines else type(error).__name__
