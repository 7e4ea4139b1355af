"""The categorical dynamics model on DeepSea's one-hot cells: its first layers' whole product against the hot entries.

    python bench/dynamics_hot_entries.py                  # about a minute on 2 cores
    python bench/dynamics_hot_entries.py --sizes 20 50 100
    python bench/dynamics_hot_entries.py --threads 2      # torch intra-op threads (default 1, as the app)

For DeepSea-N (``N * N`` one-hot cells, 2 actions), the model of a one-hot observation
as the app builds it (``output="categorical"``, raw units, one hidden layer of 256, a
32-unit prior at scale 25), milliseconds of one update's forward and backward on a batch
of 256 transitions (the cross-entropy ``DynamicsLoss`` takes), and of one planning
call (both actions of 16 cells). "whole product" multiplies the whole one-hot input
(``hot_entries=None``); "hot entries" adds the weight columns of its ones
(``hot_entries=1``, what the app sets). Both models hold the same parameters.

Every figure is the median over timed blocks (``time.perf_counter``) after an untimed
warm-up call, the two models timed in alternating blocks. A benchmark, not a test: it
prints a table and asserts nothing.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

import torch
from tensordict import TensorDict
from timing import median_seconds, print_machine_line, print_rows
from torchrl.data import OneHot

from torchrl_mbe import DynamicsLoss, DynamicsModel

SIZES = (20, 50)
BATCH = 256
PLANNED_CELLS = 16
REPEATS = 5
MODEL = {
    "num_cells": [256],
    "output": "categorical",
    "normalize": False,
    "prior_scale": 25.0,
    "prior_num_cells": [32],
}  # the app's model of a one-hot observation (app/observation.py's CATEGORICAL_DYNAMICS)


def cells(num_cells: int, count: int) -> torch.Tensor:
    return torch.eye(num_cells)[torch.randint(0, num_cells, (count,))]


def update_step(model: DynamicsModel, batch: TensorDict) -> Callable[[], None]:
    loss = DynamicsLoss(model)

    def step() -> None:
        model.zero_grad()
        loss(batch)["loss_dynamics"].backward()

    return step


def planning_call(model: DynamicsModel, observation: torch.Tensor, action: torch.Tensor) -> Callable[[], None]:
    @torch.no_grad()
    def call() -> None:
        model.predict(observation, action)

    return call


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=list(SIZES), help="DeepSea's N (N * N cells)")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    print_machine_line()
    spec = OneHot(2)
    rows = []
    for size in args.sizes:
        num_cells = size * size
        whole = DynamicsModel(num_cells, spec, **MODEL)
        hot = DynamicsModel(num_cells, spec, hot_entries=1, **MODEL)
        hot.load_state_dict(whole.state_dict())
        batch = TensorDict(
            {
                "observation": cells(num_cells, BATCH),
                "action": spec.rand((BATCH,)),
                ("next", "observation"): cells(num_cells, BATCH),
            },
            [BATCH],
        )
        observation = cells(num_cells, PLANNED_CELLS).expand(2, PLANNED_CELLS, num_cells)
        action = torch.eye(2, dtype=torch.long).unsqueeze(1).expand(2, PLANNED_CELLS, 2)
        updates = median_seconds({"whole": update_step(whole, batch), "hot": update_step(hot, batch)}, repeats=REPEATS)
        plans = median_seconds(
            {"whole": planning_call(whole, observation, action), "hot": planning_call(hot, observation, action)},
            repeats=REPEATS,
        )
        for name, timings in (("update", updates), ("planning call", plans)):
            rows.append(
                [
                    str(size),
                    name,
                    f"{timings['whole'] * 1e3:.2f}",
                    f"{timings['hot'] * 1e3:.2f}",
                    f"{timings['hot'] / timings['whole']:.2f}",
                ]
            )
    print_rows(
        "categorical dynamics model on one-hot cells, ms",
        ["N", "call", "whole product", "hot entries", "hot / whole"],
        rows,
    )


if __name__ == "__main__":
    main()
