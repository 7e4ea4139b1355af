"""How a MiniGrid run's greedy policies fail: each member's best policy played greedily, its failed episodes described.

    python bench/minigrid_failures.py RUN_DIR                 # a population's run directory (seed<s>/best_policy.pt)
    python bench/minigrid_failures.py RUN_DIR --episodes 200  # more evaluation episodes per member (default 100)
    python bench/minigrid_failures.py RUN_DIR --eps 0.05      # a random action with probability 0.05 (default 0: greedy)

For each member of the run (its config from ``RUN_DIR/.hydra/config.yaml``), the greedy
actor of its ``best_policy.pt`` (e-greedy with ``--eps``) plays ``--episodes`` episodes, one at a time, from the final
evaluation's start states (seed + 20,000). A failed episode is one that ends without the
goal. For the successes and the failures apart, it prints: how many, the median length, the
median of the most steps spent on one cell facing one way (a policy stuck in place spends
nearly every step there), how many opened a door, and the share of each MiniGrid action
taken. A diagnostic, not a test: it asserts nothing. About 20 s a member on one core.
"""

from __future__ import annotations

import argparse
import collections
import statistics
from dataclasses import dataclass, field
from pathlib import Path

import torch
from minigrid.core.actions import Actions
from omegaconf import OmegaConf
from tensordict.nn import TensorDictSequential
from torchrl.envs import EnvBase, ExplorationType, set_exploration_type, step_mdp
from torchrl.modules import EGreedyModule

from torchrl_mbe.app.dqn import build_dqn_agent
from torchrl_mbe.app.environments import make_run_env
from torchrl_mbe.envs import resolve_env_id
from torchrl_mbe.envs.registry import SUITE_TASKS


@dataclass
class Episodes:
    """What the episodes of one outcome (successes or failures) had."""

    lengths: list[int] = field(default_factory=list)
    most_steps_in_one_place: list[int] = field(default_factory=list)
    doors_opened: int = 0
    actions: collections.Counter = field(default_factory=collections.Counter)

    def line(self, outcome: str) -> str:
        if not self.lengths:
            return f"  {outcome}: none"
        taken = sum(self.actions.values())
        shares = ", ".join(
            f"{Actions(action).name} {count / taken:.0%}" for action, count in self.actions.most_common()
        )
        return (
            f"  {outcome}: {len(self.lengths)} episodes, length median {statistics.median(self.lengths):.0f}, "
            f"most steps on one cell and heading median {statistics.median(self.most_steps_in_one_place):.0f}, "
            f"a door opened in {self.doors_opened}; actions: {shares}"
        )


def minigrid_of(env: EnvBase):
    """The MiniGrid env (``unwrapped``) under a TorchRL env of one copy."""
    while hasattr(env, "base_env"):
        env = env.base_env
    return env._env.unwrapped


def door_open(grid_env) -> bool:
    return any(cell is not None and cell.type == "door" and cell.is_open for cell in grid_env.grid.grid)


def play(actor, env: EnvBase, episodes: int, eps: float) -> dict[bool, Episodes]:
    """``episodes`` episodes of ``actor`` in ``env``, e-greedy with ``eps``, described by outcome (reached the goal or not)."""
    outcomes = {True: Episodes(), False: Episodes()}
    if eps:
        actor = TensorDictSequential(actor, EGreedyModule(env.action_spec, eps_init=eps, eps_end=eps))
    exploration = ExplorationType.RANDOM if eps else ExplorationType.DETERMINISTIC
    with set_exploration_type(exploration), torch.no_grad():
        for _ in range(episodes):
            state, places, actions, opened = env.reset(), collections.Counter(), collections.Counter(), False
            while True:
                state = env.step(actor(state))
                actions[int(state["action"].argmax(-1))] += 1
                grid_env = minigrid_of(env)
                places[(tuple(grid_env.agent_pos), grid_env.agent_dir)] += 1
                opened |= door_open(grid_env)
                if state["next", "done"].any():
                    break
                state = step_mdp(state)
            described = outcomes[float(state["next", "reward"].sum()) > 0]
            described.lengths.append(sum(actions.values()))
            described.most_steps_in_one_place.append(max(places.values()))
            described.doors_opened += opened
            described.actions.update(actions)
    return outcomes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run_dir", type=Path, help="a MiniGrid population's run directory")
    parser.add_argument("--episodes", type=int, default=100, help="episodes per member (default 100)")
    parser.add_argument("--eps", type=float, default=0.0, help="probability of a random action (default 0: greedy)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    torch.manual_seed(0)  # the random actions of --eps
    config = args.run_dir / ".hydra" / "config.yaml"
    if not config.is_file():
        parser.error(f"{args.run_dir}: no .hydra/config.yaml; expected the run directory of a MiniGrid population")
    cfg = OmegaConf.load(config)
    if not any(resolve_env_id(cfg.env.name).startswith(prefix) for prefix in SUITE_TASKS):
        parser.error(f"{args.run_dir}: a run of {cfg.env.name}; expected a task of {', '.join(SUITE_TASKS)}")
    members = [cfg.seed + member for member in range(cfg.population)]
    cfg.population, cfg.processes = 1, 1
    for seed in members:
        env = make_run_env(cfg, num_envs=1, seed=seed + 20_000)
        agent = build_dqn_agent(OmegaConf.merge(cfg, {"seed": seed}), env)
        best = torch.load(args.run_dir / f"seed{seed}" / "best_policy.pt", weights_only=True)
        agent.actor.load_state_dict(best["actor"])
        outcomes = play(agent.actor, env, args.episodes, args.eps)
        print(
            f"seed {seed} (best policy at {best['frames']:,} frames): {len(outcomes[True].lengths)}/{args.episodes} reached the goal"
        )
        print(outcomes[True].line("reached the goal"))
        print(outcomes[False].line("failed"))


if __name__ == "__main__":
    main()
