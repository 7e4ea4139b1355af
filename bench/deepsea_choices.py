"""How often a learned model makes the DeepSea planner choose against the visit counts.

One agent plans every step of DeepSea-N (the rule of ``experiment=deepsea_learned``: the
diagonal Gaussian over every visited cell, the rarest predicted next cell) with a learned
``DynamicsModel`` trained online, one update of 256 per step. At each step it also scores
the two *true* next cells, and counts a step as *against the counts* when the model's
choice leads to a cell visited at least twice as often, plus two, as the other one.
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
from torchrl.data import OneHot

from torchrl_mbe import DynamicsLoss, DynamicsModel
from torchrl_mbe.envs.deepsea import DeepSeaDynamics
from torchrl_mbe.modules import DiagonalGaussianDensity


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=20)
    parser.add_argument("--min-variance", type=float, default=1e-3, help="the density's variance floor")
    parser.add_argument("--num-cells", type=int, nargs="+", default=[512], help="the model's hidden layers")
    parser.add_argument("--standardize", action="store_true", help="standardize the model's inputs and deltas (default: raw units)")
    parser.add_argument("--prior-scale", type=float, default=10.0)
    parser.add_argument("--episodes", type=int, default=150)
    parser.add_argument("--block", type=int, default=25, help="episodes per printed line")
    parser.add_argument("--seed", type=int, default=0)
    return parser.parse_args()


def main() -> None:
    args = parse_args()
    torch.manual_seed(args.seed)
    size, cells, actions = args.size, torch.eye(args.size**2), torch.eye(2).bool()
    true_dynamics = DeepSeaDynamics(OneHot(2), size=size)
    model = DynamicsModel(size**2, OneHot(2), args.num_cells, prior_scale=args.prior_scale, normalize=args.standardize)
    loss, optimizer = DynamicsLoss(model), torch.optim.Adam(model.net.parameters(), lr=1e-3)
    density = DiagonalGaussianDensity(window=None, min_variance=args.min_variance)
    visits = torch.zeros(size**2)
    capacity = args.episodes * (size - 1)
    transitions = TensorDict(
        {"observation": torch.zeros(capacity, size**2), "action": torch.zeros(capacity, 2, dtype=torch.bool), ("next", "observation"): torch.zeros(capacity, size**2)},
        [capacity],
    )
    against_counts, steps, steps_taken, start = 0, 0, 0, time.perf_counter()
    print(f"DeepSea-{size}, hidden {args.num_cells}, {'standardized' if args.standardize else 'raw units'}, "
          f"prior {args.prior_scale}, variance floor {args.min_variance:g}, seed {args.seed}")
    for episode in range(1, args.episodes + 1):
        observation, rights = cells[0], 0
        density.update(observation[None])
        visits[0] += 1
        for _ in range(size - 1):
            candidates = TensorDict({"observation": observation.expand(2, -1), "action": actions}, [2])
            with torch.no_grad():
                predicted = model(candidates.clone())["predicted_observation"]
            true_next = true_dynamics(candidates.clone())["predicted_observation"]
            choice = int(density.score(predicted).argmax())
            chosen_visits, other_visits = visits[true_next.argmax(-1)][[choice, 1 - choice]]
            against_counts += int(chosen_visits >= 2 * other_visits + 2)
            steps += 1
            next_observation = true_next[choice]
            rights += int(next_observation.argmax() % size > observation.argmax() % size)
            transitions[steps_taken] = TensorDict({"observation": observation, "action": actions[choice], ("next", "observation"): next_observation})
            steps_taken += 1
            density.update(next_observation[None])
            visits[next_observation.argmax()] += 1
            observation = next_observation
            if steps_taken >= 256:
                optimizer.zero_grad()
                loss(transitions[torch.randint(steps_taken, (256,))])["loss_dynamics"].backward()
                optimizer.step()
        if rights == size - 1:
            print(f"episode {episode}: the treasure ({time.perf_counter() - start:.0f} s)")
            break
        if episode % args.block == 0:
            print(f"episodes {episode - args.block + 1}-{episode}: {against_counts} of {steps} steps against the counts "
                  f"({against_counts / steps:.1%}), last episode {rights} of {size - 1} right moves ({time.perf_counter() - start:.0f} s)")
            against_counts, steps = 0, 0


if __name__ == "__main__":
    main()
