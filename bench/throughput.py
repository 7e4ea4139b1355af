"""Throughput of MountainCar stepping, the exploration step, batched collection and the training loop.

    python bench/throughput.py                 # full run, ~15 minutes on 2 cores
    python bench/throughput.py --quick         # smoke run, about a minute
    python bench/throughput.py --out my.json   # JSON elsewhere than bench/results/
    python bench/throughput.py --threads 2     # torch intra-op threads (default 1, as the app)
    python bench/throughput.py --only training breakdown   # some sections only
    python bench/throughput.py --only population           # populations (population=N) against single runs, the headline table
    python bench/throughput.py --only gym_batch            # LunarLander batches: GymBatchEnv against SerialEnv
    python bench/throughput.py --only population --population-envs mountaincar --population-sizes 1,16,256,1024 --device cuda --compile
                                                           # populations on a GPU, against one CPU run of the same schedule

Every figure is the median over ``repeats`` timed blocks (``time.perf_counter``)
after untimed warm-up calls; variants that are compared are timed in
alternating blocks, so load changes during the run hit them alike. A benchmark, not a test: it prints a table and
writes JSON (machine, versions, figures); it asserts nothing.

Each section is a function ``(Budget) -> list[Measurement]`` named in :data:`SECTIONS`.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import functools
import itertools
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np
import tensordict
import torch
import torchrl
from hydra import compose, initialize_config_dir
from omegaconf import DictConfig
from plain_reference import Agent as PlainAgent
from plain_reference import PlainConfig
from plain_reference import ReplayBuffer as PlainReplayBuffer
from plain_reference import run as run_plain_reference
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModuleBase, TensorDictSequential
from timing import median_seconds
from torch import nn
from torchrl.collectors import Collector
from torchrl.data import OneHot, ReplayBuffer
from torchrl.envs import EnvBase, ExplorationType, GymEnv, SerialEnv, TransformedEnv, set_exploration_type
from torchrl.modules import MLP, EGreedyModule, QValueActor

import torchrl_mbe
from torchrl_mbe import DynamicsModel, ModelBasedExplorationPolicy, NoveltyPlanner, RollingGaussianDensity, make_env
from torchrl_mbe.app import register_configs, train
from torchrl_mbe.app.dqn import build_dqn_agent as build_agent
from torchrl_mbe.app.dqn import fit_q_input_norm, update_q
from torchrl_mbe.app.replay import SUCCESSOR_KEY, ReplayTransitions, make_replay_buffer
from torchrl_mbe.envs import GymBatchEnv
from torchrl_mbe.envs.make import dqn_transforms
from torchrl_mbe.envs.registry import resolve_env_id

RESULTS_DIR = Path(__file__).parent / "results"
CONF_DIR = Path(__file__).resolve().parents[1] / "conf"
TRAIN_SCRIPT = Path(__file__).resolve().parents[1] / "train.py"
LOOP_ALONE = (
    "logger=none",
    "progress_bar=false",
    "eval.episodes=0",
    "eval.final_episodes=0",
    "train.episodes=1000000",
    "train.stop_when_solved=false",
)
"""Overrides that leave the training loop alone: no logging, evaluation or early stop."""


PAPER_LOOP = (
    "experiment=paper_mountaincar",
    "logger=none",
    "progress_bar=false",
    "eval.episodes=0",
    "eval.final_episodes=0",
    "train.episodes=100000",
    "algo.learning_starts=200",
    "dynamics.learning_starts=64",
)
"""The paper's schedule (Table 1: one Q and one dynamics update per frame, batches of
16 and 64), with updates starting after 200 (Q) and 64 (dynamics) frames instead of
10,000 so that a short run measures the loop with its updates; no evaluation."""


@dataclass(frozen=True)
class Budget:
    """What to measure and for how long: ``repeats`` timed blocks of ``calls`` calls after ``warmup`` calls.

    A collector block is ``collector_batches`` batches of ``collector_steps`` steps of every env.
    A training-loop figure is the median of ``train_repeats`` runs of ``train_frames`` frames.
    """

    warmup: int
    repeats: int
    calls: int
    collector_batches: int
    collector_steps: int
    train_frames: int
    train_repeats: int
    reference_frames: int
    population_frames: int
    population_sizes: tuple[int, ...]
    population_envs: tuple[str, ...] = ("mountaincar", "cartpole", "acrobot", "lunarlander")
    population_device: str = "cpu"  # the populations' device (the app's ``device``); single CPU runs compare
    population_compile: bool = False  # the populations' update compiled (the app's ``compile``)


FULL = Budget(
    warmup=200,
    repeats=7,
    calls=500,
    collector_batches=10,
    collector_steps=50,
    train_frames=3000,
    train_repeats=3,
    reference_frames=20_000,
    population_frames=4000,
    population_sizes=(1, 5, 20, 100),
)
QUICK = Budget(
    warmup=10,
    repeats=2,
    calls=20,
    collector_batches=2,
    collector_steps=10,
    train_frames=1000,
    train_repeats=1,
    reference_frames=3000,
    population_frames=2000,
    population_sizes=(1, 5),
)


@dataclass
class Measurement:
    section: str
    name: str
    value: float
    unit: str


def q_actor(spec: OneHot) -> QValueActor:
    """The paper's Q-network: one hidden layer of 48 ReLU units."""
    network = MLP(out_features=spec.space.n, num_cells=[48], activation_class=nn.ReLU)
    return QValueActor(network, spec=spec, in_keys=["observation"])


def model_based_policy(
    actor: QValueActor, spec: OneHot, num_envs: int, eps: float = 1.0
) -> ModelBasedExplorationPolicy:
    """Explores with constant probability ``eps``: one window of the last 50 states per env."""
    batch_shape = (num_envs,) if num_envs > 1 else ()
    density = RollingGaussianDensity(2, window=50, batch_shape=batch_shape)
    planner = NoveltyPlanner(DynamicsModel(2, spec), density, spec)
    return ModelBasedExplorationPolicy(actor, planner, eps_init=eps, eps_end=eps)


def egreedy_policy(actor: QValueActor, spec: OneHot, eps: float = 1.0) -> TensorDictSequential:
    return TensorDictSequential(actor, EGreedyModule(spec, eps_init=eps, eps_end=eps))


def bench_gym_stepping(budget: Budget) -> list[Measurement]:
    """(a) gymnasium's MountainCar-v0 stepped with random actions: the physical reference."""
    step = gymnasium_random_step("MountainCar-v0")
    timing = median_seconds({"step": step}, warmup=budget.warmup, repeats=budget.repeats, calls=budget.calls * 20)
    return [Measurement("gym", "gymnasium MountainCar-v0 env.step", 1 / timing["step"], "steps/s")]


def gymnasium_random_step(env_id: str) -> Callable[[], None]:
    """One step of ``gym.make(env_id)`` (seeded 0) with a random action, resetting at the episode's end."""
    env = gym.make(env_id)
    env.reset(seed=0)
    actions = itertools.cycle(np.random.default_rng(0).integers(env.action_space.n, size=1000).tolist())

    def step() -> None:
        _, _, terminated, truncated, _ = env.step(next(actions))
        if terminated or truncated:
            env.reset()

    return step


def bench_gym_batch(budget: Budget) -> list[Measurement]:
    """(i) LunarLander-v3 with random actions, as a single run (8 copies) and a 5-member population ((8, 5)) step it.

    ``GymBatchEnv`` (make_env's gym backend) against TorchRL's ``SerialEnv`` of
    ``GymEnv`` copies (the same episodes), both under make_env's transforms, and
    gymnasium's own step, one env at a time, as the floor.
    """
    steps = {"gymnasium LunarLander-v3 env.step": gymnasium_random_step("LunarLander-v3")}
    copies = {"gymnasium LunarLander-v3 env.step": 1}
    for batch_shape in ((8,), (8, 5)):
        num_copies = math.prod(batch_shape)
        serial = SerialEnv(num_copies, functools.partial(GymEnv, "LunarLander-v3"))
        for name, base_env in (
            ("SerialEnv of GymEnv", serial),
            ("GymBatchEnv", GymBatchEnv("LunarLander-v3", batch_shape)),
        ):
            env = TransformedEnv(base_env, dqn_transforms())
            env.set_seed(0)
            label = f"{name}, {num_copies} copies {tuple(env.batch_size)}"
            steps[label], copies[label] = batch_random_step(env), num_copies
    timing = median_seconds(steps, warmup=budget.warmup // 10, repeats=budget.repeats, calls=budget.calls // 5)
    return [Measurement("gym_batch", name, copies[name] / seconds, "env-steps/s") for name, seconds in timing.items()]


def batch_random_step(env: EnvBase) -> Callable[[], None]:
    """One step of every copy of ``env`` with random actions, resetting the copies that are done."""
    carrier = env.reset()

    def step() -> None:
        nonlocal carrier
        _, carrier = env.step_and_maybe_reset(env.rand_action(carrier))

    return step


def call_on_next(policy: TensorDictModuleBase, inputs: Iterator[TensorDictBase]) -> TensorDictBase:
    return policy(next(inputs))


def bench_exploration_step(budget: Budget) -> list[Measurement]:
    """(b) One policy call under ExplorationType.RANDOM: model-based vs EGreedyModule.

    With eps = 1 every call explores (the model-based policy plans); with eps = 0
    (``greedy step``) none does, and the model-based policy only adds the window update.
    """
    spec = OneHot(3, dtype=torch.int64)
    low, high = torch.tensor([-1.2, -0.07]), torch.tensor([0.6, 0.07])
    results = []
    for batch, eps in ((1, 1.0), (64, 1.0), (1, 0.0)):
        batch_size = (batch,) if batch > 1 else ()
        states = [low + (high - low) * torch.rand(*batch_size, 2) for _ in range(100)]
        inputs = itertools.cycle([TensorDict({"observation": state}, batch_size) for state in states])
        actor = q_actor(spec)
        policies = {
            "model-based": model_based_policy(actor, spec, batch, eps),
            "egreedy": egreedy_policy(actor, spec, eps),
        }
        label = f"batch {batch}" + (", greedy step (eps=0)" if eps == 0 else "")
        with set_exploration_type(ExplorationType.RANDOM), torch.no_grad():
            timing = median_seconds(
                {name: functools.partial(call_on_next, policy, inputs) for name, policy in policies.items()},
                warmup=budget.warmup,
                repeats=budget.repeats,
                calls=budget.calls,
            )
        for name, seconds in timing.items():
            results.append(Measurement("exploration", f"{name} policy call, {label}", seconds * 1e3, "ms/call"))
        ratio = timing["model-based"] / timing["egreedy"]
        results.append(Measurement("exploration", f"model-based / egreedy, {label}", ratio, "x"))
    return results + planned_step_parts(budget, spec, low, high)


def planned_step_parts(budget: Budget, spec: OneHot, low: torch.Tensor, high: torch.Tensor) -> list[Measurement]:
    """What a planned exploring step on one state adds to the actor call, part by part.

    The window update (every step), the Gaussian's refit and the scores of the
    predicted states (an exploring step after an update), and the dynamics
    rollout over every action (one ``DynamicsModel`` call); and what tensordict
    0.14 adds to every ``TensorDictModule`` output (``TensorDict.from_any`` looks
    for pandas on each call; tensordict 0.15 skips it for tensors, torchrl 0.14 pins < 0.15).
    """
    actor = q_actor(spec)
    policy = model_based_policy(actor, spec, 1)
    planner, novelty = policy.planner, policy.novelty
    states = itertools.cycle([low + (high - low) * torch.rand(2) for _ in range(100)])
    inputs = itertools.cycle([TensorDict({"observation": next(states)}, []) for _ in range(100)])
    sequences, predictions = planner._action_sequences(), torch.rand(3, 2)
    for _ in range(novelty.window):
        novelty.update(next(states))

    def update_refit_and_score() -> None:
        novelty.update(next(states))
        novelty.score(predictions)

    parts = {
        "planned step part: actor call (QValueActor)": functools.partial(call_on_next, actor, inputs),
        "planned step part: window update": lambda: novelty.update(next(states)),
        "planned step part: window update, refit and score": update_refit_and_score,
        "planned step part: dynamics rollout over 3 actions": lambda: planner._rollout(next(states), sequences),
        "of the actor call: TensorDict.from_any(tensor)": functools.partial(TensorDict.from_any, predictions),
    }
    with torch.no_grad():
        timing = median_seconds(parts, warmup=budget.warmup, repeats=budget.repeats, calls=budget.calls)
    return [Measurement("exploration", name, seconds * 1e3, "ms/call") for name, seconds in timing.items()]


def bench_collection(budget: Budget) -> list[Measurement]:
    """(c) Collector env-steps/s on the torch MountainCar with N envs, and the gym backend (a GymEnv, a GymBatchEnv)."""
    setups = [("torch", 1), ("torch", 8), ("torch", 64), ("torch", 256), ("torch", 1024), ("gym", 1), ("gym", 8)]
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
    timing = median_seconds(next_batch, warmup=1, repeats=budget.repeats, calls=budget.collector_batches)
    for collector in collectors:
        collector.shutdown()
    return [
        Measurement("collection", name, frames_per_batch[name] / seconds, "env-steps/s")
        for name, seconds in timing.items()
    ]


def paper_config(*overrides: str) -> DictConfig:
    """The app's config (``conf/``) with :data:`PAPER_LOOP` and then ``overrides`` applied."""
    register_configs()
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base=None):
        return compose("config", overrides=[*PAPER_LOOP, *overrides])


def training_frames_per_s(cfg: DictConfig) -> float:
    """Frames/s of one ``torchrl_mbe.app.train(cfg)`` run in a temporary directory (a population's: each member's).

    The summary's figure: frames over the loop's wall time, without building the
    env and agent before the loop or saving the checkpoint after it.
    """
    with tempfile.TemporaryDirectory() as run_dir:
        summary = train(cfg, run_dir)
    return summary["members"][0]["frames_per_s"] if "members" in summary else summary["frames_per_s"]


def app_frames_per_s_in_new_process(*overrides: str) -> float:
    """Frames/s of ``python train.py`` with :data:`LOOP_ALONE` and ``overrides``, in a process of its own.

    For ``compile=true``: a process that has compiled once traces the next run's
    losses from warm in-memory caches, which a user's run never has (Inductor's
    on-disk cache, which it does have, stays).
    """
    with tempfile.TemporaryDirectory() as run_dir:
        command = [sys.executable, str(TRAIN_SCRIPT), *LOOP_ALONE, *overrides, f"hydra.run.dir={run_dir}"]
        subprocess.run(command, check=True, capture_output=True)
        return json.loads((Path(run_dir) / "summary.json").read_text())["frames_per_s"]


def bench_training_loop(budget: Budget) -> list[Measurement]:
    """(d) Frames/s of the whole training loop, model-based (gaussian) vs e-greedy exploration, same schedule.

    ``per-step`` is the paper's loop (one frame, then its updates); ``fpb=64`` collects
    64 frames (64 / N steps of each of N envs) and then runs their 64 Q and 64
    dynamics updates. ``eps annealed``: x0.9995 per frame after 200 frames (eps is
    0.25 after 3,000 frames, so ~57% of the frames plan); ``eps=1``: every frame plans.
    """
    loops = {
        "per-step N=1, eps annealed": ("collector.frames_per_batch=1",),
        "per-step N=1, eps=1": ("collector.frames_per_batch=1", "algo.eps_end=1.0"),
        **{f"fpb=64 N={n}, eps annealed": ("collector.frames_per_batch=64", f"env.num_envs={n}") for n in (1, 8, 64)},
    }
    configs = {
        (loop, exploration): paper_config(
            *overrides, f"exploration={exploration}", f"train.max_frames={budget.train_frames}"
        )
        for loop, overrides in loops.items()
        for exploration in ("gaussian", "egreedy")
    }
    runs = {key: [] for key in configs}
    for _ in range(budget.train_repeats):
        for key, cfg in configs.items():
            runs[key].append(training_frames_per_s(cfg))
    results = []
    for loop in loops:
        frames_per_s = {
            exploration: statistics.median(runs[loop, exploration]) for exploration in ("gaussian", "egreedy")
        }
        for exploration, value in frames_per_s.items():
            results.append(Measurement("training", f"{loop}, {exploration}", value, "frames/s"))
        ratio = frames_per_s["egreedy"] / frames_per_s["gaussian"]
        results.append(Measurement("training", f"{loop}: gaussian / egreedy time per frame", ratio, "x"))
    return results


def default_config(*overrides: str) -> DictConfig:
    """The app's default config with the loop alone (:data:`LOOP_ALONE`), and ``overrides``."""
    register_configs()
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base=None):
        return compose("config", overrides=[*LOOP_ALONE, *overrides])


def plain_config_of(cfg: DictConfig) -> PlainConfig:
    """The plain reference's settings for the app's composed ``cfg`` (a gymnasium env, one hidden width)."""
    algo, dynamics = cfg.algo, cfg.dynamics
    if (
        len({*algo.num_cells}) != 1
        or len({*dynamics.num_cells}) != 1
        or algo.target_update != "hard"
        or not algo.double_dqn
    ):
        raise ValueError("the plain reference implements equal hidden layers, hard target copies and double DQN only")
    return PlainConfig(
        env_id=resolve_env_id(cfg.env.name),
        num_envs=cfg.env.num_envs,
        exploration=cfg.exploration.name,
        max_frames=cfg.train.max_frames,
        frames_per_batch=cfg.collector.frames_per_batch,
        n_steps=algo.n_steps,
        gamma=algo.gamma,
        hidden_size=algo.num_cells[0],
        dynamics_hidden_size=dynamics.num_cells[0],
        q_lr=algo.lr,
        batch_size=algo.batch_size,
        max_grad_norm=algo.max_grad_norm,
        target_update_interval=algo.hard_update_interval,
        buffer_size=cfg.buffer.size,
        learning_starts=algo.learning_starts,
        updates_per_frame=algo.updates_per_frame,
        eps_init=algo.eps_init,
        eps_end=algo.eps_end,
        eps_annealing_frames=algo.eps_annealing_frames,
        window=cfg.exploration.window if cfg.exploration.name == "gaussian" else 50,
        dynamics_lr=dynamics.lr,
        dynamics_batch_size=dynamics.batch_size,
        dynamics_learning_starts=dynamics.learning_starts,
        dynamics_updates_per_frame=dynamics.updates_per_frame,
        seed=cfg.seed,
    )


def bench_against_plain_reference(budget: Budget) -> list[Measurement]:
    """(f) The default MountainCar config through ``train(cfg)`` beside ``bench/plain_reference.py``.

    Both run the same networks, schedule, targets and exploring rule (the reference
    gets every setting from the composed config, :func:`plain_config_of`) for ``reference_frames`` frames
    from a cold start, with 1 env (16 frames per batch) and 16 envs (64 frames per
    batch: the torch-batched env in the app, gymnasium's SyncVectorEnv in the
    reference), each variant timed ``train_repeats`` times in alternation. The
    default (gaussian, 16 envs) runs once more with ``compile=true``, tracing
    included, in a process of its own (:func:`app_frames_per_s_in_new_process`),
    against the same plain figure.
    """
    frames = budget.reference_frames
    plain_variants = sorted(
        (exploration, envs, per_batch)
        for exploration in ("gaussian", "egreedy")
        for envs, per_batch in ((1, 16), (16, 64))
    )
    app_variants = [(*variant, False) for variant in plain_variants] + [("gaussian", 16, 64, True)]
    app, plain = {v: [] for v in app_variants}, {v: [] for v in plain_variants}
    for _ in range(budget.train_repeats):
        for exploration, envs, per_batch, compiled in app_variants:
            overrides = (
                f"exploration={exploration}",
                f"env.num_envs={envs}",
                f"collector.frames_per_batch={per_batch}",
                f"train.max_frames={frames}",
            )
            if compiled:
                app[exploration, envs, per_batch, compiled].append(
                    app_frames_per_s_in_new_process(*overrides, "compile=true")
                )
                continue
            cfg = default_config(*overrides)
            app[exploration, envs, per_batch, compiled].append(training_frames_per_s(cfg))
            plain[exploration, envs, per_batch].append(run_plain_reference(plain_config_of(cfg))["frames_per_s"])
    results = []
    for exploration, envs, per_batch, compiled in app_variants:
        name = f"{exploration}, N={envs}"
        app_fps = statistics.median(app[exploration, envs, per_batch, compiled])
        plain_fps = statistics.median(plain[exploration, envs, per_batch])
        loop = "train(cfg), compile=true" if compiled else "train(cfg)"
        if not compiled:
            results.append(Measurement("reference", f"{name}: plain PyTorch reference", plain_fps, "frames/s"))
        results += [
            Measurement("reference", f"{name}: {loop}", app_fps, "frames/s"),
            Measurement("reference", f"{name}: {loop} / plain", app_fps / plain_fps, "x"),
        ]
    return results


def bench_population(budget: Budget) -> list[Measurement]:
    """(h) ``population=N`` on each env's default config (``population_envs``), against single runs.

    For N in ``population_sizes``: frames/s per member and summed over the N members,
    over ``population_frames`` frames per member (the loop alone: no evaluation), on
    ``population_device`` (in the app's default processes: one per core, one on a GPU), compiled with ``population_compile``.
    N = 1 is the single-run path, so N single runs in sequence sum to its frames/s;
    ``/ N single runs`` is the population's summed frames/s over that. The plain
    PyTorch reference (``bench/plain_reference.py``) runs each env's per-member
    schedule once (on gymnasium's env), for ``/ plain``; off the CPU, one eager CPU run
    of the same schedule too, for ``/ one CPU run``.
    """
    device, compiled = budget.population_device, budget.population_compile
    on_device = (f"device={device}", f"compile={str(compiled).lower()}")
    results = []
    for env in budget.population_envs:
        schedule = (f"env={env}", f"train.max_frames={budget.population_frames}")
        per_member = {
            members: training_frames_per_s(default_config(*schedule, f"population={members}", *on_device))
            for members in budget.population_sizes
        }
        plain = run_plain_reference(plain_config_of(default_config(*schedule)))["frames_per_s"]
        results.append(Measurement("population", f"{env}: plain PyTorch reference, one run", plain, "frames/s"))
        cpu = training_frames_per_s(default_config(*schedule)) if device != "cpu" else None
        if cpu is not None:
            results.append(Measurement("population", f"{env}: one CPU run", cpu, "frames/s"))
        for members, frames_per_s in per_member.items():
            summed = members * frames_per_s
            results += [
                Measurement("population", f"{env} N={members}: frames/s per member", frames_per_s, "frames/s"),
                Measurement("population", f"{env} N={members}: summed", summed, "frames/s"),
                Measurement("population", f"{env} N={members}: summed / N single runs", summed / per_member[1], "x"),
                Measurement("population", f"{env} N={members}: summed / plain", summed / plain, "x"),
            ]
            if cpu is not None:
                results.append(Measurement("population", f"{env} N={members}: summed / one CPU run", summed / cpu, "x"))
    return results


def bench_loop_breakdown(budget: Budget) -> list[Measurement]:
    """(e) Milliseconds of each part of one frame of the paper's per-step loop (N=1, eps=1).

    The collector step (policy, env step, TorchRL bookkeeping) for each policy and for
    the collector's own random policy (no network: the floor), then the per-frame work
    of ``torchrl_mbe.app.dqn``: storing the frame, one Q update (DQNLoss, Adam,
    HardUpdate; with two of its parts, ``of which``), one dynamics update and the
    dynamics error on the new frame.
    """
    cfg = paper_config("algo.eps_end=1.0", "exploration=gaussian")
    env = make_env("mountaincar", seed=0)
    agent = build_agent(cfg, env)
    egreedy_agent = build_agent(paper_config("algo.eps_end=1.0", "exploration=egreedy"), env)
    collectors = {
        name: Collector(make_env("mountaincar", seed=0), policy, frames_per_batch=1, total_frames=-1)
        for name, policy in (
            ("gaussian", agent.explorer.policy),
            ("egreedy", egreedy_agent.explorer.policy),
            ("random", None),
        )
    }
    steps = {f"collector step, {name} policy": functools.partial(next, iter(c)) for name, c in collectors.items()}
    buffer = make_replay_buffer(cfg.buffer, cfg.device)
    transitions = ReplayTransitions(1, cfg.algo.gamma)
    for _ in range(300):
        buffer.extend(transitions(steps["collector step, gaussian policy"]()))
    agent.explorer.training.model.fit_normalization(buffer, next_observation_key=SUCCESSOR_KEY)
    frame = steps["collector step, gaussian policy"]().reshape(-1).clone()
    transition = transitions(frame)
    q_batch = buffer.sample(cfg.algo.batch_size)
    parts = {
        **steps,
        "store the frame (buffer.extend)": functools.partial(buffer.extend, transition),
        "Q update (sample 16, DQNLoss, Adam, HardUpdate)": functools.partial(update_q, agent, buffer),
        "  of which: buffer.sample(16)": functools.partial(buffer.sample, cfg.algo.batch_size),
        "  of which: DQNLoss forward on 16": functools.partial(agent.q_loss, q_batch),
        "dynamics update (sample 64, DynamicsLoss, Adam)": functools.partial(agent.explorer.training.update, buffer),
        "dynamics error on the new frame": functools.partial(agent.explorer.observe, frame),
    }
    timing = median_seconds(parts, warmup=budget.warmup, repeats=budget.repeats, calls=budget.calls)
    for collector in collectors.values():
        collector.shutdown()
    return [Measurement("breakdown", name, seconds * 1e3, "ms/frame") for name, seconds in timing.items()]


def bench_updates(budget: Budget) -> list[Measurement]:
    """(g) One Q update and one dynamics update of the default config, through TorchRL and written plainly.

    The default MountainCar config (batches of 256, 2x256 Q-network, double DQN,
    clipping, fused Adam): ``update_q`` and ``update_dynamics`` of ``train(cfg)``,
    eager and with ``compile=true`` (timed after its tracing, in the warm-up), against
    ``Agent.update_q`` and ``Agent.update_dynamics`` of ``bench/plain_reference.py``.
    All sample from buffers holding the same 2,560 collected frames.
    """
    cfg = default_config()
    env = make_env("mountaincar", seed=0, num_envs=cfg.env.num_envs)
    agents = {"eager": build_agent(cfg, env), "compiled": build_agent(default_config("compile=true"), env)}
    buffer = make_replay_buffer(cfg.buffer, cfg.device)
    transitions = ReplayTransitions(cfg.algo.n_steps, cfg.algo.gamma)
    collector = Collector(
        env, agents["eager"].explorer.policy, frames_per_batch=cfg.collector.frames_per_batch, total_frames=2560
    )
    for batch in collector:
        stored = transitions(batch)
        if stored is not None:
            buffer.extend(stored)
    collector.shutdown()
    for agent in agents.values():
        fit_q_input_norm(agent, buffer)
        agent.explorer.training.model.fit_normalization(buffer, next_observation_key=SUCCESSOR_KEY)
    observation_size, num_actions = (
        env.observation_spec_unbatched["observation"].shape[-1],
        env.action_spec_unbatched.space.n,
    )
    plain = PlainAgent(plain_config_of(cfg), observation_size, num_actions, rng=np.random.default_rng(0))
    plain_buffer = plain_buffer_of(buffer, cfg.algo.gamma)
    parts = {}
    for name, agent in agents.items():
        parts[f"Q update, train(cfg) {name}"] = functools.partial(update_q, agent, buffer)
        parts[f"dynamics update, train(cfg) {name}"] = functools.partial(agent.explorer.training.update, buffer)
    parts["Q update, plain reference"] = functools.partial(plain.update_q, plain_buffer)
    parts["dynamics update, plain reference"] = functools.partial(plain.update_dynamics, plain_buffer)
    parts["  of which: buffer.sample(256), train(cfg)"] = functools.partial(buffer.sample, cfg.algo.batch_size)
    parts["  of which: buffer.sample(256), plain reference"] = functools.partial(
        plain_buffer.sample, cfg.algo.batch_size, plain.rng
    )
    timing = median_seconds(parts, warmup=budget.warmup, repeats=budget.repeats, calls=budget.calls)
    results = [Measurement("updates", name, seconds * 1e3, "ms/update") for name, seconds in timing.items()]
    for update in ("Q update", "dynamics update"):
        for name in agents:
            ratio = timing[f"{update}, train(cfg) {name}"] / timing[f"{update}, plain reference"]
            results.append(Measurement("updates", f"{update}, train(cfg) {name} / plain", ratio, "x"))
    return results


def plain_buffer_of(buffer: ReplayBuffer, gamma: float) -> PlainReplayBuffer:
    """The plain reference's replay arrays holding the transitions of the app's ``buffer``."""
    stored = buffer[: len(buffer)]
    plain = PlainReplayBuffer(len(buffer), stored["observation"].shape[-1])
    plain.obs[:] = stored["observation"].numpy()
    plain.action[:] = stored["action"].argmax(-1).numpy()
    plain.next_obs[:] = stored[SUCCESSOR_KEY].numpy()
    plain.ret[:] = stored["next", "reward"].squeeze(-1).numpy()
    plain.bootstrap_obs[:] = stored["next", "observation"].numpy()
    bootstrap = ~stored["next", "terminated"].squeeze(-1)
    plain.bootstrap_discount[:] = (gamma ** stored["steps_to_next_obs"].squeeze(-1) * bootstrap).numpy()
    plain.size = len(buffer)
    return plain


SECTIONS: dict[str, Callable[[Budget], list[Measurement]]] = {
    "gym": bench_gym_stepping,
    "gym_batch": bench_gym_batch,
    "exploration": bench_exploration_step,
    "collection": bench_collection,
    "training": bench_training_loop,
    "breakdown": bench_loop_breakdown,
    "reference": bench_against_plain_reference,
    "updates": bench_updates,
    "population": bench_population,
}
"""Run in order; each returns its figures, named after the section."""


def machine() -> dict[str, object]:
    cpu = platform.processor()
    if Path("/proc/cpuinfo").exists():
        names = [
            line.split(":", 1)[1].strip()
            for line in Path("/proc/cpuinfo").read_text().splitlines()
            if line.startswith("model name")
        ]
        cpu = names[0] if names else cpu
    return {
        "cpu": cpu,
        "nproc": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "load_average_1min": os.getloadavg()[0],
        "torchrl_mbe": str(Path(torchrl_mbe.__file__).parent),
        "git_commit": git_describe(Path(torchrl_mbe.__file__).parent),
        "python": platform.python_version(),
        "torch": torch.__version__,
        "torchrl": torchrl.__version__,
        "tensordict": tensordict.__version__,
        "gymnasium": gym.__version__,
    }


def git_describe(directory: Path) -> str | None:
    """``git describe --always --dirty`` of the checkout holding ``directory`` (None outside git)."""
    try:
        done = subprocess.run(
            ["git", "-C", str(directory), "describe", "--always", "--dirty"], capture_output=True, text=True, check=True
        )
    except (OSError, subprocess.CalledProcessError):
        return None
    return done.stdout.strip()


def print_table(measurements: list[Measurement]) -> None:
    width = max(len(m.name) for m in measurements)
    section = None
    for m in measurements:
        if m.section != section:
            section = m.section
            print(f"\n[{section}]")
        print(f"  {m.name:<{width}}  {m.value:>12,.3f} {m.unit}")


def headline(measurements: list[Measurement]) -> str:
    """The population section as one table, an env a row: one run against the plain reference, N members against N single runs.

    "one run" is ``population=1`` (the single-run path) and "plain" the plain PyTorch
    reference's single run on the same per-member schedule; a column per population
    size measured, and per size against one CPU run where the populations ran on
    another device. Empty without the population section.
    """
    values = {m.name: m.value for m in measurements if m.section == "population"}
    envs = list(dict.fromkeys(name.split(" N=1:")[0] for name in values if " N=1: frames/s per member" in name))
    if not envs:
        return ""
    sizes = sorted({int(name.split(" N=")[1].split(":")[0]) for name in values if " N=" in name} - {1})
    ratios = [("summed / N single runs", "summed / {n} single runs"), ("summed / plain", "summed / plain")]
    if any(name.endswith("summed / one CPU run") for name in values):
        ratios.append(("summed / one CPU run", "summed / one CPU run"))
    columns = ["env", "plain reference", "one run", "one run / plain"]
    columns += [f"N={n}: {title.format(n=n)}" for _, title in ratios for n in sizes]
    rows = []
    for env in envs:
        plain, one = values[f"{env}: plain PyTorch reference, one run"], values[f"{env} N=1: frames/s per member"]
        cells = [env, f"{plain:,.0f} frames/s", f"{one:,.0f} frames/s", f"{one / plain:.2f}x"]
        cells += [f"{values[f'{env} N={n}: {ratio}']:.2f}x" for ratio, _ in ratios for n in sizes]
        rows.append("| " + " | ".join(cells) + " |")
    return "\n".join(["| " + " | ".join(columns) + " |", "| --- " * len(columns) + "|", *rows])


def population_sizes(text: str) -> tuple[int, ...]:
    """``--population-sizes``: member counts, the first 1 (the single run every ratio divides by)."""
    sizes = tuple(int(size) for size in text.split(","))
    if sizes[0] != 1 or min(sizes) < 1:
        raise argparse.ArgumentTypeError(f"{text}: expected positive member counts starting with 1, e.g. 1,16,256")
    return sizes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="short smoke run")
    parser.add_argument(
        "--out", type=Path, help="JSON output path (default: bench/results/throughput-<date>-<HHMM>.json)"
    )
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads (default 1, as the app)")
    parser.add_argument("--only", nargs="+", choices=list(SECTIONS), help="run these sections only (default: all)")
    parser.add_argument("--note", default="", help="free text stored in the JSON (e.g. which code was measured)")
    parser.add_argument("--population-sizes", type=population_sizes, help="population section: e.g. 1,16,256,1024")
    parser.add_argument("--population-envs", nargs="+", help="population section: envs (default: the four classic)")
    parser.add_argument("--device", default="cpu", help="population section: the populations' device (e.g. cuda)")
    parser.add_argument("--compile", action="store_true", help="population section: compile the populations' update")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    torch.set_flush_denormal(True)  # as train(cfg) and the plain reference do
    budget = dataclasses.replace(
        QUICK if args.quick else FULL,
        population_device=args.device,
        population_compile=args.compile,
        **({"population_sizes": args.population_sizes} if args.population_sizes else {}),
        **({"population_envs": tuple(args.population_envs)} if args.population_envs else {}),
    )
    torch.manual_seed(0)
    started = datetime.datetime.now()
    environment = machine()
    measurements = [m for name, section in SECTIONS.items() if name in (args.only or SECTIONS) for m in section(budget)]
    print_table(measurements)
    table = headline(measurements)
    if table:
        print(f"\n[headline] populations against single runs and the plain reference\n{table}")
    suffix = ("-quick" if args.quick else "") + (f"-threads{args.threads}" if args.threads != 1 else "")
    out = args.out or RESULTS_DIR / f"throughput-{started:%Y-%m-%d-%H%M}{suffix}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    report = {
        "date": started.isoformat(timespec="seconds"),
        "quick": args.quick,
        "note": args.note,
        "budget": asdict(budget),
        "machine": environment,
        "measurements": [asdict(m) for m in measurements],
    }
    out.write_text(json.dumps(report, indent=2) + "\n")
    print(f"\nwrote {out}")


if __name__ == "__main__":
    main()
