"""Where the training loop's time goes: cProfile around ``train(cfg)``.

    python bench/profile_loop.py                                   # the default config, 10,000 frames
    python bench/profile_loop.py env.num_envs=1 collector.frames_per_batch=16 "algo.num_cells=[64,64]"
    python bench/profile_loop.py population=5                      # a population step

Any Hydra override of the app applies; logging, evaluation and early stopping are
off so that the profile shows the loop alone. Prints frames/s and the functions
with the largest cumulative time. A benchmark tool, not a test.
"""

from __future__ import annotations

import cProfile
import pstats
import sys
import tempfile

from throughput import default_config

from torchrl_mbe.app import train


def main(overrides: list[str], top: int = 30) -> None:
    cfg = default_config("train.max_frames=10000", *overrides)
    profiler = cProfile.Profile()
    with tempfile.TemporaryDirectory() as run_dir:
        profiler.enable()
        summary = train(cfg, run_dir)
        profiler.disable()
    for member in summary.get("members", [summary]):  # a population's summary lists its members'
        print(f"seed {member['seed']}: {member['frames']} frames, {member['frames_per_s']} frames/s under the profiler")
    pstats.Stats(profiler).sort_stats("cumulative").print_stats(top)


if __name__ == "__main__":
    main(sys.argv[1:])
