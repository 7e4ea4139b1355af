"""Throughput of MountainCar stepping, the exploration step and batched collection.

    python bench/throughput.py                 # full run, a few minutes on 2 cores
    python bench/throughput.py --quick         # smoke run, seconds
    python bench/throughput.py --out my.json   # JSON elsewhere than bench/results/
    python bench/throughput.py --threads 1     # torch.set_num_threads(1) first

Every figure is the median over ``repeats`` timed blocks (``time.perf_counter``)
after untimed warm-up calls; variants that are compared are timed in
alternating blocks, so load changes during the run hit them alike. A benchmark, not a test: it prints a table and
writes JSON (machine, versions, figures); it asserts nothing.

Each section is a function ``(Budget) -> list[Measurement]`` listed in
:data:`SECTIONS`; a new figure (e.g. full training-loop frames/s of
``torchrl_mbe.training.train``) is one more such function.
"""
from __future__ import annotations

import argparse
import datetime
import functools
import itertools
import json
import os
import platform
import statistics
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np
import tensordict
import torch
import torchrl
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModuleBase, TensorDictSequential
from torch import nn
from torchrl.collectors import Collector
from torchrl.data import OneHot
from torchrl.envs import ExplorationType, set_exploration_type
from torchrl.modules import MLP, EGreedyModule, QValueActor

from torchrl_mbe import DynamicsModel, ModelBasedExplorationPolicy, NoveltyPlanner, RollingGaussianDensity, make_env

RESULTS_DIR = Path(__file__).parent / "results"


@dataclass(frozen=True)
class Budget:
    """How long to measure: ``repeats`` timed blocks of ``calls`` calls after ``warmup`` calls.

    A collector block is ``collector_batches`` batches of ``collector_steps`` steps of every env.
    """

    warmup: int
    repeats: int
    calls: int
    collector_batches: int
    collector_steps: int


FULL = Budget(warmup=200, repeats=7, calls=500, collector_batches=10, collector_steps=50)
QUICK = Budget(warmup=10, repeats=2, calls=20, collector_batches=2, collector_steps=10)


@dataclass
class Measurement:
    section: str
    name: str
    value: float
    unit: str


def seconds_per_call(fns: dict[str, Callable[[], object]], *, warmup: int, repeats: int, calls: int) -> dict[str, float]:
    """Median wall time of one call of each function.

    After ``warmup`` untimed calls of each, ``repeats`` rounds time a block of
    ``calls`` calls of every function in turn, so that a change of machine load
    during the run hits the variants being compared alike.
    """
    for fn in fns.values():
        for _ in range(warmup):
            fn()
    blocks = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            start = time.perf_counter()
            for _ in range(calls):
                fn()
            blocks[name].append((time.perf_counter() - start) / calls)
    return {name: statistics.median(times) for name, times in blocks.items()}


def q_actor(spec: OneHot) -> QValueActor:
    """The paper's Q-network: one hidden layer of 48 ReLU units."""
    network = MLP(out_features=spec.space.n, num_cells=[48], activation_class=nn.ReLU)
    return QValueActor(network, spec=spec, in_keys=["observation"])


def model_based_policy(actor: QValueActor, spec: OneHot, num_envs: int) -> ModelBasedExplorationPolicy:
    """Explores on every step (eps = 1): one window of the last 50 states per env."""
    batch_shape = (num_envs,) if num_envs > 1 else ()
    density = RollingGaussianDensity(2, window=50, batch_shape=batch_shape)
    planner = NoveltyPlanner(DynamicsModel(2, spec), density, spec)
    return ModelBasedExplorationPolicy(actor, planner, eps_init=1.0, eps_end=1.0)


def egreedy_policy(actor: QValueActor, spec: OneHot) -> TensorDictSequential:
    return TensorDictSequential(actor, EGreedyModule(spec, eps_init=1.0, eps_end=1.0))


def bench_gym_stepping(budget: Budget) -> list[Measurement]:
    """(a) gymnasium's MountainCar-v0 stepped with random actions: the physical reference."""
    env = gym.make("MountainCar-v0")
    env.reset(seed=0)
    actions = itertools.cycle(np.random.default_rng(0).integers(3, size=1000).tolist())

    def step() -> None:
        _, _, terminated, truncated, _ = env.step(next(actions))
        if terminated or truncated:
            env.reset()

    timing = seconds_per_call({"step": step}, warmup=budget.warmup, repeats=budget.repeats, calls=budget.calls * 20)
    return [Measurement("gym", "gymnasium MountainCar-v0 env.step", 1 / timing["step"], "steps/s")]


def call_on_next(policy: TensorDictModuleBase, inputs: Iterator[TensorDictBase]) -> TensorDictBase:
    return policy(next(inputs))


def bench_exploration_step(budget: Budget) -> list[Measurement]:
    """(b) One policy call under ExplorationType.RANDOM, eps = 1: model-based vs EGreedyModule."""
    spec = OneHot(3, dtype=torch.int64)
    low, high = torch.tensor([-1.2, -0.07]), torch.tensor([0.6, 0.07])
    results = []
    for batch in (1, 64):
        batch_size = (batch,) if batch > 1 else ()
        states = [low + (high - low) * torch.rand(*batch_size, 2) for _ in range(100)]
        inputs = itertools.cycle([TensorDict({"observation": state}, batch_size) for state in states])
        actor = q_actor(spec)
        policies = {"model-based": model_based_policy(actor, spec, batch), "egreedy": egreedy_policy(actor, spec)}
        with set_exploration_type(ExplorationType.RANDOM), torch.no_grad():
            timing = seconds_per_call(
                {name: functools.partial(call_on_next, policy, inputs) for name, policy in policies.items()},
                warmup=budget.warmup,
                repeats=budget.repeats,
                calls=budget.calls,
            )
        for name, seconds in timing.items():
            results.append(Measurement("exploration", f"{name} policy call, batch {batch}", seconds * 1e3, "ms/call"))
        ratio = timing["model-based"] / timing["egreedy"]
        results.append(Measurement("exploration", f"model-based / egreedy, batch {batch}", ratio, "x"))
    return results


def bench_collection(budget: Budget) -> list[Measurement]:
    """(c) Collector env-steps/s on the torch MountainCar with N envs, and a GymEnv / SerialEnv reference."""
    setups = [("torch", 1), ("torch", 8), ("torch", 64), ("gym", 1), ("gym", 8)]
    collectors, next_batch, frames_per_batch = [], {}, {}
    for (backend, num_envs), policy_name in itertools.product(setups, ("model-based", "egreedy")):
        env = make_env("mountaincar", num_envs=num_envs, backend=backend, seed=0)
        actor = q_actor(env.action_spec)
        if policy_name == "model-based":
            policy = model_based_policy(actor, env.action_spec, num_envs)
        else:
            policy = egreedy_policy(actor, env.action_spec)
        name = f"{backend} N={num_envs}, {policy_name}"
        frames_per_batch[name] = budget.collector_steps * num_envs
        collectors.append(Collector(env, policy, frames_per_batch=frames_per_batch[name], total_frames=-1))
        next_batch[name] = functools.partial(next, iter(collectors[-1]))
    timing = seconds_per_call(next_batch, warmup=1, repeats=budget.repeats, calls=budget.collector_batches)
    for collector in collectors:
        collector.shutdown()
    return [Measurement("collection", name, frames_per_batch[name] / seconds, "env-steps/s") for name, seconds in timing.items()]


SECTIONS: tuple[Callable[[Budget], list[Measurement]], ...] = (bench_gym_stepping, bench_exploration_step, bench_collection)
"""Run in order; each returns its figures."""


def machine() -> dict[str, object]:
    cpu = platform.processor()
    if Path("/proc/cpuinfo").exists():
        names = [line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines() if line.startswith("model name")]
        cpu = names[0] if names else cpu
    return {
        "cpu": cpu,
        "nproc": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "load_average_1min": os.getloadavg()[0],
        "python": platform.python_version(),
        "torch": torch.__version__,
        "torchrl": torchrl.__version__,
        "tensordict": tensordict.__version__,
        "gymnasium": gym.__version__,
    }


def print_table(measurements: list[Measurement]) -> None:
    width = max(len(m.name) for m in measurements)
    section = None
    for m in measurements:
        if m.section != section:
            section = m.section
            print(f"\n[{section}]")
        print(f"  {m.name:<{width}}  {m.value:>12,.3f} {m.unit}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="short smoke run")
    parser.add_argument("--out", type=Path, help="JSON output path (default: bench/results/throughput-<date>.json)")
    parser.add_argument("--threads", type=int, help="torch intra-op threads (default: torch's choice)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    budget = QUICK if args.quick else FULL
    torch.manual_seed(0)
    started = datetime.datetime.now()
    environment = machine()
    measurements = [m for section in SECTIONS for m in section(budget)]
    print_table(measurements)
    suffix = ("-quick" if args.quick else "") + (f"-threads{args.threads}" if args.threads else "")
    out = args.out or RESULTS_DIR / f"throughput-{started:%Y-%m-%d}{suffix}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    report = {
        "date": started.isoformat(timespec="seconds"),
        "quick": args.quick,
        "budget": asdict(budget),
        "machine": environment,
        "measurements": [asdict(m) for m in measurements],
    }
    out.write_text(json.dumps(report, indent=2) + "\n")
    print(f"\nwrote {out}")


if __name__ == "__main__":
    main()
