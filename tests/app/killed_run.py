"""``python killed_run.py POINT FRAMES [overrides...]``: ``train.py`` SIGKILLed at a chosen point, as a preempted job is.

POINT ``frames``: just after the first batch that brings the run to ``FRAMES`` frames or more;
``checkpoint-write``: half-way through writing the first checkpoint at ``FRAMES`` frames or more
(the ``.partial`` file holds half its bytes, the previous checkpoint stands).
"""

from __future__ import annotations

import io
import os
import runpy
import signal
import sys
from pathlib import Path

import torch

import torchrl_mbe.app.dqn as dqn_module
import torchrl_mbe.app.run as run_module

TRAIN_SCRIPT = Path(__file__).resolve().parents[2] / "train.py"


def kill_after_frames(frames: int) -> None:
    record_frames = dqn_module.record_frames

    def record_then_maybe_die(run, batch, **kwargs):
        record_frames(run, batch, **kwargs)
        if run.progress.frames >= frames:
            os.kill(os.getpid(), signal.SIGKILL)

    dqn_module.record_frames = record_then_maybe_die


def kill_while_writing_the_checkpoint(frames: int) -> None:
    save_checkpoint = run_module.save_checkpoint

    def write_half_then_die(run):
        if run.progress.frames < frames:
            return save_checkpoint(run)
        whole = io.BytesIO()
        run_module.save_atomically = lambda state, path: torch.save(state, whole)  # capture the bytes
        save_checkpoint(run)
        partial = run.run_dir / (run_module.CHECKPOINT + ".partial")
        partial.write_bytes(whole.getvalue()[: len(whole.getvalue()) // 2])
        os.kill(os.getpid(), signal.SIGKILL)

    run_module.save_checkpoint = write_half_then_die


if __name__ == "__main__":
    point, frames, overrides = sys.argv[1], int(sys.argv[2]), sys.argv[3:]
    {"frames": kill_after_frames, "checkpoint-write": kill_while_writing_the_checkpoint}[point](frames)
    sys.argv = [str(TRAIN_SCRIPT), *overrides]
    runpy.run_path(str(TRAIN_SCRIPT), run_name="__main__")
