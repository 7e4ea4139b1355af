"""How often a learned model makes the DeepSea planner choose against the visit counts.

One agent plans every step of DeepSea-N (the rule of ``experiment=deepsea_learned``: the
diagonal Gaussian over every visited cell, the rarest predicted next cell) with a learned
``DynamicsModel`` trained online, one update of 256 per step. At each step it also scores
the two *true* next cells, and counts a step as *against the counts* when the model's
choice leads to a cell visited at least twice as often, plus two, as the other one.
The choice is :class:`~torchrl_mbe.NoveltyPlanner`'s, as in the app (ties broken at random).
Prints those steps per block of episodes, and the episode of the first treasure.

    python bench/deepsea_choices.py --size 20 --min-variance 1e-8   # the density's default floor
    python bench/deepsea_choices.py --size 20 --min-variance 1e-3   # the preset's
    python bench/deepsea_choices.py --size 20 --num-cells 64 64 --standardize --min-variance 1e-8  # the preset before b9777cb
"""

from __future__ import annotations

import argparse
import time

import torch
from tensordict import TensorDict
from torchrl.data import LazyTensorStorage, OneHot, ReplayBuffer

from torchrl_mbe import DynamicsLoss, DynamicsModel, NoveltyPlanner
from torchrl_mbe.envs.deepsea import DeepSeaDynamics
from torchrl_mbe.modules import DiagonalGaussianDensity


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=20)
    parser.add_argument("--min-variance", type=float, default=1e-3, help="the density's variance floor")
    parser.add_argument("--num-cells", type=int, nargs="+", default=[512], help="the model's hidden layers")
    parser.add_argument(
        "--standardize", action="store_true", help="standardize the model's inputs and deltas (default: raw units)"
    )
    parser.add_argument("--prior-scale", type=float, default=10.0)
    parser.add_argument("--episodes", type=int, default=150)
    parser.add_argument("--block", type=int, default=25, help="episodes per printed line")
    parser.add_argument("--seed", type=int, default=0)
    return parser.parse_args()


def main() -> None:
    args = parse_args()
    torch.manual_seed(args.seed)
    size, spec = args.size, OneHot(2)
    true_dynamics = DeepSeaDynamics(spec, size=size)
    model = DynamicsModel(size**2, spec, args.num_cells, prior_scale=args.prior_scale, normalize=args.standardize)
    planner = NoveltyPlanner(model, DiagonalGaussianDensity(window=None, min_variance=args.min_variance), spec)
    loss, optimizer = DynamicsLoss(model), torch.optim.Adam(model.net.parameters(), lr=1e-3)
    replay_buffer = ReplayBuffer(storage=LazyTensorStorage(args.episodes * (size - 1)), batch_size=256)
    visits = torch.zeros(size**2)
    against_counts, steps, start = 0, 0, time.perf_counter()
    print(
        f"DeepSea-{size}, hidden {args.num_cells}, {'standardized' if args.standardize else 'raw units'}, "
        f"prior {args.prior_scale}, variance floor {args.min_variance:g}, seed {args.seed}"
    )
    for episode in range(1, args.episodes + 1):
        observation, rights = torch.eye(size**2)[0], 0
        planner.novelty.update(observation[None])
        visits[0] += 1
        for _ in range(size - 1):
            with torch.no_grad():
                action, _ = planner.plan(observation)
            choice = int(action.long().argmax())
            true_next = true_dynamics.step(observation.expand(2, -1), torch.arange(2))  # after each action
            true_cells = true_next.argmax(-1)
            against_counts += int(visits[true_cells[choice]] >= 2 * visits[true_cells[1 - choice]] + 2)
            steps += 1
            next_observation = true_next[choice]
            rights += int(next_observation.argmax() % size > observation.argmax() % size)
            replay_buffer.add(
                TensorDict({"observation": observation, "action": action, ("next", "observation"): next_observation})
            )
            planner.novelty.update(next_observation[None])
            visits[next_observation.argmax()] += 1
            observation = next_observation
            if len(replay_buffer) >= 256:
                optimizer.zero_grad()
                loss(replay_buffer.sample())["loss_dynamics"].backward()
                optimizer.step()
        if rights == size - 1:
            print(f"episode {episode}: the treasure ({time.perf_counter() - start:.0f} s)")
            break
        if episode % args.block == 0:
            print(
                f"episodes {episode - args.block + 1}-{episode}: {against_counts} of {steps} steps against the counts "
                f"({against_counts / steps:.1%}), last episode {rights} of {size - 1} right moves ({time.perf_counter() - start:.0f} s)"
            )
            against_counts, steps = 0, 0


if __name__ == "__main__":
    main()
