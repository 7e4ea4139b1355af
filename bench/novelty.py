"""The Gaussian novelty's refit on one-hot states: the dense ``eigh`` fit against the low-rank one.

    python bench/novelty.py                        # about 2 minutes on 2 cores, most of it the dense fit at D = 2,500
    python bench/novelty.py --threads 2            # torch intra-op threads (default 1, as the app)
    python bench/novelty.py --features 25 50 75    # other state sizes

For D = 2, 100, 400, 2,500 features (DeepSea's one-hot N x N grid has D = N^2: 400 at
N = 20, 2,500 at N = 50), a window of F = 50 states and one window per env
(``batch_shape=(16,)``), milliseconds of one planning step's novelty work: ``update``
with one visited state per window, which marks the fit stale, then ``score`` of 2
candidate states per window (DeepSea's 2 actions), which refits. "dense" is
``RollingGaussianDensity``'s fit for D <= F (float64 ``eigh`` of the D x D correlation,
cached as a whitening matrix), "low-rank" its fit for D > F (``eigh`` of the F x F Gram
matrix, cached as eigenpairs); each is forced at every D, and "used" says which one
``RollingGaussianDensity`` picks. "fit MB" is the size of each fit's buffers. States are
random rows of the identity.

Every figure is the median over timed blocks (``time.perf_counter``) after an untimed
warm-up call, the two fits timed in alternating blocks; a call slower than
``SLOW_CALL_S`` is timed once, its warm-up call being the figure. A benchmark, not a
test: it prints a table and asserts nothing.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable, Sequence

import torch
from timing import median_seconds, print_machine_line, print_rows

from torchrl_mbe import RollingGaussianDensity

FEATURES = (2, 100, 400, 2500)
WINDOW = 50
NUM_ENVS = 16
CANDIDATES = 2
STEPS = 64  # visited states cycled through by the timed calls
REPEATS = 5
MIN_BLOCK_S = 0.1
SLOW_CALL_S = 2.0


class DenseFit(RollingGaussianDensity):
    def _fits_low_rank(self) -> bool:
        return False


class LowRankFit(RollingGaussianDensity):
    def _fits_low_rank(self) -> bool:
        return True


def one_hot_states(num_features: int, *shape: int) -> torch.Tensor:
    return torch.eye(num_features)[torch.randint(0, num_features, shape)]


def planning_step(density: RollingGaussianDensity) -> Callable[[], None]:
    """One visited state per window, then the score of ``CANDIDATES`` states per window, on a full window."""
    num_features = density.num_features
    density.update(one_hot_states(num_features, WINDOW, NUM_ENVS))
    visits = one_hot_states(num_features, STEPS, NUM_ENVS)
    candidates = one_hot_states(num_features, STEPS, CANDIDATES, NUM_ENVS)
    step = 0

    def update_and_score() -> None:
        nonlocal step
        density.update(visits[step % STEPS])
        density.score(candidates[step % STEPS])
        step += 1

    return update_and_score


def fit_megabytes(density: RollingGaussianDensity) -> float:
    """Size of the buffers the fit caches (all but the window and its counters)."""
    window_buffers = {"states", "num_seen", "fit_stale"}
    fit = [buffer for name, buffer in density.named_buffers() if name not in window_buffers]
    return sum(buffer.numel() * buffer.element_size() for buffer in fit) / 2**20


def bench_refit(features: Sequence[int]) -> None:
    rows = []
    for num_features in features:
        dense = DenseFit(num_features, window=WINDOW, batch_shape=(NUM_ENVS,))
        low_rank = LowRankFit(num_features, window=WINDOW, batch_shape=(NUM_ENVS,))
        seconds = median_seconds(
            {"dense": planning_step(dense), "low-rank": planning_step(low_rank)},
            repeats=REPEATS,
            min_block_s=MIN_BLOCK_S,
            slow_call_s=SLOW_CALL_S,
        )
        used = "low-rank" if RollingGaussianDensity(num_features, window=WINDOW)._fits_low_rank() else "dense"
        rows.append(
            (
                str(num_features),
                used,
                f"{1e3 * seconds['dense']:.2f}" + (" (1 call)" if seconds["dense"] > SLOW_CALL_S else ""),
                f"{1e3 * seconds['low-rank']:.2f}",
                f"{seconds['dense'] / seconds['low-rank']:.1f}x",
                f"{fit_megabytes(dense):.2f}",
                f"{fit_megabytes(low_rank):.2f}",
            )
        )
    header = ("D", "used", "dense ms", "low-rank ms", "dense / low-rank", "dense fit MB", "low-rank fit MB")
    title = f"update + refit + score {CANDIDATES} states per window: F = {WINDOW}, batch_shape ({NUM_ENVS},), one-hot states"
    print_rows(title, header, rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads (default 1, as the app)")
    parser.add_argument("--features", type=int, nargs="+", default=FEATURES, help=f"state sizes D (default {FEATURES})")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    torch.set_flush_denormal(True)  # as train(cfg) does
    torch.manual_seed(0)
    started = time.perf_counter()
    print_machine_line()
    bench_refit(args.features)
    print(f"\n{time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()
