"""What a DeepSea planner with a learned model chooses, read from a population's checkpoint.

For every member and every cell it has visited, it compares the two actions' next
cells by their visit counts (the counts the diagonal density holds), and reports how
often the planner's scores prefer the less-visited one: with the learned model's
predictions, and with the true next cells (``DeepSeaDynamics``). Also the model's
error on (cell, next cell) pairs it has visited, the visits along the diagonal (the only path to the
treasure), and the score gap between the two true next cells where the
less-visited one has fewer than 20 visits: how large a model error must be to
reverse the choice there. ``--floor`` adds the same counts scored with a plain
variance floor (``min_variance``, no ``added_variance``).

    python train.py experiment=deepsea_learned env.size=30 population=2 train.episodes=200
    python bench/deepsea_frontier.py runs/deepsea/deepsea-30/dqn+diagonal/seeds0-1/checkpoint.pt --floor 1e-3
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch
from omegaconf import OmegaConf

from torchrl_mbe.app.checkpoints import load_safely
from torchrl_mbe.app.config import ConfigError
from torchrl_mbe.app.dqn import build_dqn_agent
from torchrl_mbe.app.environments import make_run_env
from torchrl_mbe.envs.deepsea import DeepSeaDynamics
from torchrl_mbe.modules import DiagonalGaussianDensity


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint", help="a checkpoint.pt of experiment=deepsea_learned (any population size)")
    parser.add_argument(
        "--floor", type=float, help="also score the true next cells with the same counts and only this variance floor"
    )
    args = parser.parse_args()
    if args.floor is not None and not args.floor > 0:
        parser.error(f"--floor {args.floor:g}: expected a variance > 0")
    checkpoint = read_deepsea_checkpoint(parser, Path(args.checkpoint))
    cfg = OmegaConf.create(checkpoint["config"])
    size, members = cfg.env.size, cfg.population
    agent = build_dqn_agent(cfg, make_run_env(cfg, num_envs=1, seed=cfg.seed))
    agent.load_state_dict(checkpoint["agent"])
    planner = agent.explorer.policy.planner
    cells = torch.eye(size**2)[:, None, None].expand(size**2, 1, members, size**2)  # (cell, env, member, D)
    actions = planner.candidate_actions
    true_dynamics = DeepSeaDynamics(planner.action_spec, size=size)
    with torch.no_grad():
        predicted = torch.stack(
            [planner.dynamics.predict(cells, actions[a].expand(*cells.shape[:-1], -1)) for a in range(2)]
        )
        true_next = torch.stack([true_dynamics.step(cells, torch.full(cells.shape[:-1], a)) for a in range(2)])
        scores = {
            "learned model": planner.novelty.score(predicted),
            "true next cells": planner.novelty.score(true_next),
        }
        if args.floor is not None:
            floored = DiagonalGaussianDensity(
                window=None, batch_shape=planner.novelty.batch_shape, min_variance=args.floor
            )
            floored.load_state_dict(
                {**planner.novelty.state_dict(), "fit_stale": torch.tensor(True)}
            )  # the sums; refit with the floor
            scores[f"true next cells, floor {args.floor:g} alone"] = floored.score(true_next)
    visits = planner.novelty.state_sum.reshape(members, size**2)
    next_cells = true_next.argmax(-1)[:, :, 0]  # (action, cell, member)
    errors = (predicted - true_next).norm(dim=-1)[:, :, 0]
    rows = torch.arange(size**2) // size
    print(f"DeepSea-{size}, {checkpoint['frames']} frames a member, density {planner.novelty}")
    for member in range(members):
        next_visits = visits[member][next_cells[:, :, member]]  # (action, cell)
        compared = (visits[member] > 0) & (rows < size - 1) & (next_visits[0] != next_visits[1])
        rare = compared & (next_visits.amin(0) < 20)
        fewer = next_visits.argmin(0)
        print(
            f"seed {cfg.seed + member}: of {int(compared.sum())} visited cells whose next cells' visits differ, the less-visited one is preferred"
        )
        for name, score in scores.items():
            score = score[:, :, 0, member]  # (action, cell)
            preferred = score.argmax(0) == fewer
            print(
                f"  with the {name}: {preferred[compared].float().mean():.1%} (where it has under 20 visits: "
                f"{preferred[rare].float().mean():.1%} of {int(rare.sum())}, score gap median {(score[0] - score[1]).abs()[rare].median():.1f})"
            )
        seen = (
            (next_visits > 0) & (visits[member] > 0) & (rows < size - 1)
        )  # both cells visited: most such pairs were tried
        print(
            f"  model error where both cells were visited: median {errors[:, :, member][seen].median():.3f}, "
            f"90th percentile {errors[:, :, member][seen].quantile(0.9):.3f} (cells are 1.41 apart)"
        )
        print(f"  visits along the diagonal: {visits[member].reshape(size, size).diagonal().int().tolist()}")


def read_deepsea_checkpoint(parser: argparse.ArgumentParser, path: Path) -> dict:
    """The checkpoint of a DeepSea run whose planner scores with the diagonal density; anything else ends in one line."""
    if not path.is_file():
        parser.error(f"{path} does not exist (a run directory's checkpoint.pt is expected)")
    try:
        checkpoint = load_safely(path)
    except ConfigError as error:
        parser.error(str(error))
    config = checkpoint.get("config", {})
    if config.get("env", {}).get("name") != "deepsea" or config.get("exploration", {}).get("name") != "diagonal":
        parser.error(
            f"{path} is not a checkpoint of env=deepsea with exploration=diagonal (experiment=deepsea_learned is)"
        )
    return checkpoint


if __name__ == "__main__":
    main()
