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

from torchrl_mbe.app import population as population_module
from torchrl_mbe.app.population import Population

TRAIN_SCRIPT = Path(__file__).resolve().parents[2] / "train.py"


def kill_after_frames(frames: int) -> None:
    record = Population.record

    def record_then_maybe_die(population, batch, **kwargs):
        record(population, batch, **kwargs)
        if population.frames >= frames:
            os.kill(os.getpid(), signal.SIGKILL)

    Population.record = record_then_maybe_die


def kill_while_writing_the_checkpoint(frames: int) -> None:
    save_checkpoint = Population.save_checkpoint

    def write_half_then_die(population):
        if population.frames < frames:
            return save_checkpoint(population)
        whole = io.BytesIO()
        population_module.save_atomically = lambda state, path: torch.save(state, whole)  # capture the bytes
        save_checkpoint(population)
        partial = population.run_dir / (population_module.CHECKPOINT + ".partial")
        partial.write_bytes(whole.getvalue()[: len(whole.getvalue()) // 2])
        os.kill(os.getpid(), signal.SIGKILL)

    Population.save_checkpoint = write_half_then_die


if __name__ == "__main__":
    point, frames, overrides = sys.argv[1], int(sys.argv[2]), sys.argv[3:]
    {"frames": kill_after_frames, "checkpoint-write": kill_while_writing_the_checkpoint}[point](frames)
    sys.argv = [str(TRAIN_SCRIPT), *overrides]
    runpy.run_path(str(TRAIN_SCRIPT), run_name="__main__")
