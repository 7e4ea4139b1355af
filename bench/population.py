"""A population's DQN update against the same members updated one after another, their replay sampling and their network calls.

    python bench/population.py              # about two minutes on 2 cores
    python bench/population.py --threads 2  # torch intra-op threads (default 1, as the app)

For N = 1, 5, 20, 100 members and hidden layers 64x64 and 256x256 (MountainCar's
sizes: 2 observations, 3 actions), one update is: sample 256 transitions per member,
DQN loss (double DQN, smooth L1), backward, gradient clipping, fused Adam, target
update. "population" is one update of all N members (``MembersMLP``, ``PopulationDQNLoss``,
per-member clipping, ``PopulationReplayBuffer``; docs/architecture.md, "Where the member dimension lives");
"N singles" is N separate networks, each with its own TorchRL ``DQNLoss``, Adam,
``HardUpdate`` and ``TensorDictReplayBuffer(LazyTensorStorage)``, updated in sequence:
the work of N single runs. Speed-up is N singles' time over the population's; "vs N x one
single" divides N times the first row's single update (MEMBERS starts at 1) instead: N
networks updated in turn share the caches, so each is slower than a lone single run's.
"network calls" times one call of the members' Q-network, as ``MembersMLP`` (batched
products) and as TorchRL's ``MultiAgentMLP`` (its vmapped call) holding the same parameters,
plain and NoisyNet, on the batch of an exploring step (16 envs) and of an update (256), with
and without a backward.

Every figure is the median over timed blocks (``time.perf_counter``) after untimed
warm-up calls; the variants compared are timed in alternating blocks, so load changes
hit them alike. A benchmark, not a test: it prints tables and asserts nothing.
"""

from __future__ import annotations

import argparse
import functools
import itertools
import logging
import time
from collections.abc import Callable, Sequence

import torch
from tensordict import TensorDict
from timing import median_seconds, print_machine_line, print_rows
from torchrl.data import LazyTensorStorage, OneHot, TensorDictReplayBuffer
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import QValueActor
from torchrl.objectives import DQNLoss, HardUpdate, LossModule

from torchrl_mbe.app.optim import clip_grad_norm_per_member_
from torchrl_mbe.app.replay import PopulationReplayBuffer
from torchrl_mbe.modules.networks import make_members_mlp, make_per_action_mlp, make_population_q_actor
from torchrl_mbe.objectives.population import PopulationDQNLoss

OBSERVATION_SIZE = 2
ACTION_SPEC = OneHot(3)
BATCH_SIZE = 256
CAPACITY = 10_000
MEMBERS = (1, 5, 20, 100)
CALL_MEMBERS = (1, 3, 5, 20)
CALL_BATCHES = (16, BATCH_SIZE)  # an exploring step's 16 envs, an update's batch
CALL_NOISE = (None, 0.5)  # plain linear layers, NoisyNet's
HIDDEN_LAYERS = ((64, 64), (256, 256))
MAX_GRAD_NORM = 10.0
HARD_UPDATE_INTERVAL = 150  # conf/tuned/mountaincar_dqn.yaml
REPEATS = 5
MIN_BLOCK_S = 0.1
LOSS_OPTIONS = {"delay_value": True, "double_dqn": True, "loss_function": "smooth_l1", "action_space": ACTION_SPEC}


def transitions(num_rows: int, members: Sequence[int] = ()) -> TensorDict:
    """Random MountainCar-shaped transitions, batch ``[num_rows, *members]``."""
    shape = (num_rows, *members)
    flags = torch.rand(*shape, 1) < 0.005
    return TensorDict(
        observation=torch.randn(*shape, OBSERVATION_SIZE),
        action=ACTION_SPEC.rand(shape),
        next=TensorDict(
            observation=torch.randn(*shape, OBSERVATION_SIZE),
            reward=-torch.ones(*shape, 1),
            done=flags,
            terminated=flags,
            batch_size=shape,
        ),
        batch_size=shape,
    )


def torchrl_buffer(data: TensorDict) -> TensorDictReplayBuffer:
    """TorchRL's uniform buffer as the app makes it (``compilable=True``), holding ``data``."""
    buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(CAPACITY, compilable=True), compilable=True)
    buffer.extend(data)
    return buffer


def dqn_update(
    loss: LossModule, sample: Callable[[], TensorDict], clip: Callable[[list[torch.Tensor]], torch.Tensor]
) -> Callable[[], None]:
    """One update of ``loss`` on ``sample()``: loss, backward, ``clip``, fused Adam, hard target update."""
    loss.make_value_estimator(gamma=0.99)
    parameters = list(loss.parameters())
    optimizer = torch.optim.Adam(parameters, lr=1e-3, fused=True)
    target_updater = HardUpdate(loss, value_network_update_interval=HARD_UPDATE_INTERVAL)

    def update() -> None:
        batch = sample().exclude("index")
        optimizer.zero_grad(set_to_none=True)
        loss(batch)["loss"].backward()
        clip(parameters)
        optimizer.step()
        target_updater.step()

    return update


def population_update(num_members: int, hidden: Sequence[int]) -> Callable[[], None]:
    buffer = PopulationReplayBuffer(CAPACITY, num_members)
    buffer.extend(transitions(CAPACITY, (num_members,)))
    actor = make_population_q_actor(OBSERVATION_SIZE, ACTION_SPEC, hidden, num_members)
    clip = functools.partial(clip_grad_norm_per_member_, max_norm=MAX_GRAD_NORM, num_members=num_members)
    return dqn_update(PopulationDQNLoss(actor, **LOSS_OPTIONS), functools.partial(buffer.sample, BATCH_SIZE), clip)


def single_update(hidden: Sequence[int]) -> Callable[[], None]:
    buffer = torchrl_buffer(transitions(CAPACITY))
    actor = QValueActor(
        make_per_action_mlp(OBSERVATION_SIZE, ACTION_SPEC, hidden), spec=ACTION_SPEC, in_keys=["observation"]
    )
    clip = functools.partial(torch.nn.utils.clip_grad_norm_, max_norm=MAX_GRAD_NORM)
    return dqn_update(DQNLoss(actor, **LOSS_OPTIONS), functools.partial(buffer.sample, BATCH_SIZE), clip)


def in_sequence(calls: list[Callable[[], object]]) -> Callable[[], None]:
    def call_each() -> None:
        for call in calls:
            call()

    return call_each


def bench_updates() -> None:
    rows = []
    for hidden in HIDDEN_LAYERS:
        lone_single_ms = (
            None  # the N = 1 row's single network: a single run's update, without N networks sharing the caches
        )
        for num_members in MEMBERS:
            seconds = median_seconds(
                {
                    "population": population_update(num_members, hidden),
                    "singles": in_sequence([single_update(hidden) for _ in range(num_members)]),
                },
                repeats=REPEATS,
                warmup=2,
                min_block_s=MIN_BLOCK_S,
            )
            population_ms, singles_ms = 1e3 * seconds["population"], 1e3 * seconds["singles"]
            lone_single_ms = lone_single_ms or singles_ms / num_members
            rows.append(
                (
                    "x".join(map(str, hidden)),
                    str(num_members),
                    f"{population_ms:.2f}",
                    f"{population_ms / num_members:.3f}",
                    f"{singles_ms:.2f}",
                    f"{singles_ms / num_members:.3f}",
                    f"{singles_ms / population_ms:.2f}x",
                    f"{num_members * lone_single_ms / population_ms:.2f}x",
                )
            )
    header = ("hidden", "N", "population ms", "ms/member", "N singles ms", "ms/member", "speed-up", "vs N x one single")
    print_rows(f"update: sample {BATCH_SIZE} per member, DQN loss, backward, clip, fused Adam, target", header, rows)


def bench_sampling() -> None:
    rows = []
    for num_members in MEMBERS:
        data = transitions(CAPACITY, (num_members,))
        population = PopulationReplayBuffer(CAPACITY, num_members)
        population.extend(data)
        separate = [torchrl_buffer(data[:, member].clone()) for member in range(num_members)]
        shared_rows = torchrl_buffer(data)
        seconds = median_seconds(
            {
                "population": functools.partial(population.sample, BATCH_SIZE),
                "separate": in_sequence([functools.partial(buffer.sample, BATCH_SIZE) for buffer in separate]),
                "shared rows": functools.partial(shared_rows.sample, BATCH_SIZE),
            },
            repeats=REPEATS,
            warmup=2,
            min_block_s=MIN_BLOCK_S,
        )
        rows.append(
            (str(num_members), *(f"{1e3 * seconds[name]:.3f}" for name in ("population", "separate", "shared rows")))
        )
    header = ("N", "PopulationReplayBuffer", "N TorchRL buffers", "one TorchRL buffer, rows shared")
    print_rows(f"sample: ms for {BATCH_SIZE} transitions per member, capacity {CAPACITY:,}", header, rows)


def network_call(network: torch.nn.Module, states: torch.Tensor, backward: bool) -> Callable[[], None]:
    """One call of ``network`` on ``states`` while exploring (NoisyNet layers draw on their noise): an exploring step's (no gradient) or an update's (with its backward)."""

    def forward() -> None:
        with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
            network(states)

    def forward_and_backward() -> None:
        with set_exploration_type(ExplorationType.RANDOM):
            network(states).sum().backward()

    return forward_and_backward if backward else forward


def bench_network_calls() -> None:
    hidden = HIDDEN_LAYERS[-1]
    rows = []
    for noise_std, num_members in itertools.product(CALL_NOISE, CALL_MEMBERS):
        members, vmapped = (
            make_members_mlp(
                OBSERVATION_SIZE, ACTION_SPEC.space.n, hidden, num_members, noise_std=noise_std, batched=batched
            )
            for batched in (True, False)
        )
        vmapped.load_state_dict(members.state_dict())
        for batch, backward in itertools.product(CALL_BATCHES, (False, True)):
            states = torch.randn(batch, num_members, OBSERVATION_SIZE)
            seconds = median_seconds(
                {
                    "MembersMLP": network_call(members, states, backward),
                    "MultiAgentMLP": network_call(vmapped, states, backward),
                },
                repeats=REPEATS,
                warmup=2,
                min_block_s=MIN_BLOCK_S,
            )
            members_ms, vmapped_ms = 1e3 * seconds["MembersMLP"], 1e3 * seconds["MultiAgentMLP"]
            rows.append(
                (
                    "NoisyNet" if noise_std else "plain",
                    str(num_members),
                    str(batch),
                    "forward and backward" if backward else "forward",
                    f"{members_ms:.3f}",
                    f"{vmapped_ms:.3f}",
                    f"{vmapped_ms / members_ms:.2f}x",
                )
            )
    header = ("layers", "N", "batch", "call", "MembersMLP ms", "MultiAgentMLP ms", "speed-up")
    print_rows(f"network calls: the members' {'x'.join(map(str, hidden))} Q-network, one call", header, rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads (default 1, as the app)")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    logging.getLogger("torchrl").setLevel(
        logging.WARNING
    )  # one "Initialized LazyTensorStorage" line per buffer otherwise
    torch.set_flush_denormal(True)  # as train(cfg) does
    torch.manual_seed(0)
    started = time.perf_counter()
    print_machine_line()
    bench_sampling()
    bench_network_calls()
    bench_updates()
    print(f"\n{time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()
