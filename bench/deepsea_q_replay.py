"""Replays a DeepSea run's own transitions through the Q-learning alone, under other Q settings.

In ``experiment=deepsea_oracle`` and the presets built on it eps stays 1: the planner takes
every step and the Q-network never acts, so what a run collects does not depend on its Q
settings. This script reads a population's checkpoint (its replay buffer holds every member's
transitions in the order they were collected), trains a fresh Q side of the app
(``build_dqn_agent``, TorchRL's DQNLoss, ``DQNAgent.learn_q``'s schedule) on each member's
stream with the given config overrides, and prints the episode of the first evaluation
(every ``eval.every_frames``) whose greedy policy takes the treasure: at every cell of the
diagonal, the only path there, the action of the member's treasure episodes. Also a Q-network's
second-layer units that no stored observation activates (dead ReLUs) at the end.

    python train.py experiment=deepsea_categorical env.size=30 population=5 train.episodes=2000
    python bench/deepsea_q_replay.py RUN_DIR/checkpoint.pt algo.lr=2e-3 algo.standardize_inputs=true --repeats 2
    python bench/deepsea_q_replay.py RUN_DIR/checkpoint.pt algo.lr=5e-4 algo.standardize_inputs=false --repeats 2
"""

from __future__ import annotations

import argparse
import logging
import statistics
import time
from pathlib import Path

import torch
from deepsea_frontier import read_deepsea_checkpoint
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException
from tensordict import TensorDict, TensorDictBase

from torchrl_mbe.app.dqn import DQNAgent, build_dqn_agent
from torchrl_mbe.app.environments import make_run_env
from torchrl_mbe.app.replay import make_replay_buffer
from torchrl_mbe.app.run import crossed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "checkpoint", help="a checkpoint.pt of a DeepSea preset with eps 1 (experiment=deepsea_categorical)"
    )
    parser.add_argument("overrides", nargs="*", help="config overrides of the replayed Q side, e.g. algo.lr=5e-4")
    parser.add_argument(
        "--repeats", type=int, default=1, help="initializations per member (torch seeds seed, seed+1000, ...)"
    )
    args = parser.parse_args()
    if args.repeats < 1:
        parser.error(f"--repeats {args.repeats}: expected at least 1 initialization per member")
    logging.getLogger("torchrl").setLevel(logging.WARNING)  # it announces every storage it initializes
    checkpoint = read_deepsea_checkpoint(parser, Path(args.checkpoint))
    cfg = replay_config(parser, checkpoint["config"], args.overrides)
    stored = stored_transitions(checkpoint)
    print(
        f"DeepSea-{cfg.env.size}, {stored.shape[0]} frames a member; Q side: {OmegaConf.to_container(cfg.algo)}",
        flush=True,
    )
    solved_episodes = []
    for member in range(stored.shape[1]):
        seed = checkpoint["config"]["seed"] + member
        transitions = stored[:, member]
        treasure_path, first_treasure = treasure_episodes(transitions, cfg.env.size)
        if treasure_path is None:
            print(f"seed {seed}: no treasure in its transitions, nothing for a greedy policy to follow", flush=True)
            continue
        for repeat in range(args.repeats):
            started = time.perf_counter()
            solved, dead = replay(cfg, seed, transitions, treasure_path, torch_seed=seed + 1000 * repeat)
            solved_episodes.append(solved)
            print(
                f"seed {seed} init {repeat}: first treasure at episode {first_treasure}, "
                f"greedy takes it at episode {solved if solved is not None else '- (not by the end)'}, "
                f"{dead} of {cfg.algo.num_cells[-1]} second-layer units dead, {time.perf_counter() - started:.0f} s",
                flush=True,
            )
    reached = [episode for episode in solved_episodes if episode is not None]
    median = f", median episode {statistics.median(reached):g}" if reached else ""
    print(f"solved {len(reached)} of {len(solved_episodes)} replays{median}")


def replay_config(parser: argparse.ArgumentParser, config: dict, overrides: list[str]) -> DictConfig:
    """The checkpoint's config as one agent (``population=1``) with ``overrides``; a bad one ends in one line."""
    cfg = OmegaConf.merge(OmegaConf.create(config), {"population": 1, "logger": {"log_every_updates": 0}})
    OmegaConf.set_struct(cfg, True)  # an override of a key the config lacks is an error
    try:
        cfg = OmegaConf.merge(cfg, OmegaConf.from_dotlist(overrides))
    except OmegaConfBaseException as error:
        parser.error(f"overrides {' '.join(overrides)}: {str(error).splitlines()[0]}")
    if cfg.algo.eps_end != 1.0 or cfg.env.num_envs != 1:
        parser.error(
            f"a replay needs algo.eps_end=1 and env.num_envs=1 (the Q-network never acts, one episode after another); got {cfg.algo.eps_end} and {cfg.env.num_envs}"
        )
    return cfg


def stored_transitions(checkpoint: dict) -> TensorDictBase:
    """The population's replay buffer as ``[frames, members]``, in the order it was filled (it never wrapped)."""
    buffer = checkpoint["kept"]["replay_buffer"]
    storage = TensorDict(buffer["storage"]).auto_batch_size_(batch_dims=2)
    if buffer["cursor"] != buffer["size"]:
        raise SystemExit("the replay buffer has wrapped around: its order is no longer the order of collection")
    return storage[: buffer["size"]]


def treasure_episodes(transitions: TensorDictBase, size: int) -> tuple[torch.Tensor | None, int | None]:
    """The actions of a member's treasure episodes along the diagonal, and the first one's episode (``None`` without one)."""
    episodes = transitions.reshape(-1, size)  # one env: whole episodes one after another
    cells = episodes["observation"].argmax(-1)
    on_diagonal = (cells == torch.arange(size) * (size + 1)).all(-1)
    treasure = on_diagonal & (episodes["next", "reward"][:, -1, 0] > 0.5)
    if not treasure.any():
        return None, None
    return episodes["action"][treasure][0].argmax(-1), treasure.nonzero()[0].item() + 1


def replay(
    cfg: DictConfig, seed: int, transitions: TensorDictBase, treasure_path: torch.Tensor, *, torch_seed: int
) -> tuple[int | None, int]:
    """Trains a fresh Q side on ``transitions`` batch by batch; returns the episode its greedy policy first takes the treasure, and its dead units."""
    torch.manual_seed(torch_seed)
    agent = build_dqn_agent(cfg, make_run_env(cfg, num_envs=1, seed=seed))
    replay_buffer = make_replay_buffer(cfg.buffer, "cpu")
    size, batch_frames = cfg.env.size, cfg.collector.frames_per_batch
    held_back = cfg.algo.n_steps if cfg.algo.n_steps > 1 else 0  # n-step windows wait for the next batch
    solved = None
    for frames in range(batch_frames, transitions.shape[0] + held_back + 1, batch_frames):
        if frames - held_back > len(replay_buffer):
            replay_buffer.extend(transitions[len(replay_buffer) : frames - held_back])
        agent.learn_q(replay_buffer, frames, batch_frames)
        if crossed(frames, batch_frames, cfg.eval.every_frames) and takes_treasure(agent, treasure_path):
            solved = frames // size
            break
    return solved, dead_units(agent, transitions["observation"])


@torch.no_grad()
def takes_treasure(agent: DQNAgent, treasure_path: torch.Tensor) -> bool:
    """Whether the greedy action at every diagonal cell is the treasure episodes' action there."""
    size = treasure_path.numel()
    diagonal = torch.eye(size * size)[torch.arange(size) * (size + 1)]
    greedy = agent.actor(TensorDict(observation=diagonal, batch_size=[size]))["action"].argmax(-1)
    return bool((greedy == treasure_path).all())


@torch.no_grad()
def dead_units(agent: DQNAgent, observations: torch.Tensor) -> int:
    """Last hidden layer units that no observation activates."""
    network = agent.actor.module[0].module  # QValueActor's MLP, behind Sequential(Standardize, MLP) if standardized
    mlp, features = (
        (network[1], agent.q_input_norm(observations)) if agent.standardizes_inputs else (network, observations)
    )
    for layer in list(mlp)[:-1]:
        features = layer(features)
    return int((features.amax(0) <= 0).sum())


if __name__ == "__main__":
    main()
