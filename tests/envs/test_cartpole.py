from __future__ import annotations

import torch
from torchrl.collectors import Collector
from torchrl.envs import GymWrapper
from torchrl.envs.utils import check_env_specs

from torchrl_mbe import make_env
from torchrl_mbe.envs import BatchedCartPoleEnv, GymBatchEnv

BALANCE = torch.tensor([0.5, 1.0, 10.0, 2.0], dtype=torch.float64)
"""Push towards ``BALANCE @ state > 0``: keeps the pole up for the whole 500-step limit."""


def test_start_states_are_uniform_in_gymnasiums_range():
    start = BatchedCartPoleEnv(4096, seed=0).reset()["observation"]
    assert start.abs().max() <= 0.05 and (start.amin(0) < -0.0499).all() and (start.amax(0) > 0.0499).all()
    torch.testing.assert_close(start.mean(0), torch.zeros(4), atol=0.003, rtol=0)


def test_trajectories_equal_gymnasiums_including_termination_and_truncation(gymnasium_episode):
    """Same states, same actions: failing cart and pole fall at once, random pushes soon after, balancing lasts 500."""
    num_envs, horizon = 12, 500
    env = BatchedCartPoleEnv(num_envs, seed=0)
    td = env.reset()
    edge = torch.tensor(
        [
            [2.39, 1.0, 0.0, 0.0],  # runs off the right end in one step
            [-2.39, -1.0, 0.0, 0.0],  # off the left end
            [2.39, -1.0, 0.0, 0.0],  # at the end but leaving it: goes on
            [0.0, 0.0, 0.2, 1.0],  # the pole tips past 12 degrees in one step
            [0.0, 0.0, -0.2, -1.0],
            [0.0, 2.0, 0.1, -2.5],  # fast, swinging back
        ],
        dtype=torch.float64,
    )
    env.physical_state[: len(edge)] = edge
    starts = env.physical_state.clone()
    balancing = torch.arange(num_envs) >= 9
    actions = torch.randint(2, (horizon, num_envs), generator=torch.Generator().manual_seed(0))
    ours = []
    for t in range(horizon):
        actions[t] = torch.where(balancing, (env.physical_state @ BALANCE > 0).long(), actions[t])
        td = env.step(td.set("action", torch.nn.functional.one_hot(actions[t], 2)))
        ours.append(td["next"].clone())
        td = td["next"]
    ours = torch.stack(ours, 1)
    lengths = []
    for i in range(num_envs):
        observations, outcomes, _ = gymnasium_episode("CartPole-v1", starts[i], actions[:, i])
        length = len(outcomes)
        torch.testing.assert_close(ours[i, :length]["observation"], observations, atol=1e-5, rtol=0)
        assert outcomes == list(
            zip(*(ours[i, :length][key].squeeze(-1).tolist() for key in ("reward", "terminated", "truncated")))
        ), i
        lengths.append(length)
    assert [lengths[i] for i in (0, 1, 3, 4)] == [1] * 4 and min(lengths[2], lengths[5]) > 1
    assert max(lengths[:9]) < 100 and lengths[9:] == [500] * 3
    assert ours[9:, -1]["truncated"].all() and not ours[9:]["terminated"].any()


def test_partial_resets_in_a_collector_restart_exactly_the_fallen_poles():
    env = make_env("cartpole", num_envs=4, seed=0)
    collector = Collector(env, None, frames_per_batch=400, total_frames=400)
    data = next(iter(collector))  # (4 envs, 100 steps) of random pushes
    collector.shutdown()
    done = data["next", "done"].squeeze(-1)
    assert done.sum(1).min() >= 2, "random pushes drop every pole within ~50 steps"
    after_done = torch.zeros_like(done)
    after_done[:, 1:] = done[:, :-1]
    assert (data["step_count"].squeeze(-1)[after_done] == 0).all() and data["is_init"].squeeze(-1)[after_done].all()
    assert data["observation"][after_done].abs().max() <= 0.05
    continuing = ~after_done[:, 1:]
    torch.testing.assert_close(data["observation"][:, 1:][continuing], data["next", "observation"][:, :-1][continuing])


def test_make_env_steps_several_cartpoles_in_torch_and_one_through_gymnasium():
    env = make_env("cartpole", num_envs=4, seed=0)
    assert isinstance(env.base_env, BatchedCartPoleEnv) and env.batch_size == (4,)
    check_env_specs(env)
    assert isinstance(make_env("cartpole").base_env, GymWrapper)
    assert isinstance(make_env("cartpole", num_envs=2, backend="gym").base_env, GymBatchEnv)
