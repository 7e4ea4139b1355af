from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch
from tensordict.nn import TensorDictModule
from torchrl.collectors import Collector
from torchrl.envs import GymWrapper
from torchrl.modules import MLP, QValueActor

from torchrl_mbe import DynamicsModel, ModelBasedExplorationPolicy, NoveltyPlanner, RollingGaussianDensity, make_env
from torchrl_mbe.envs import BatchedMountainCarEnv, GymBatchEnv


def pump_energy(observation: torch.Tensor) -> torch.Tensor:
    """Push along the velocity: reaches the flag from any start in ~100 steps."""
    return torch.nn.functional.one_hot(2 * (observation[..., 1] >= 0).long(), 3)


PUMP = TensorDictModule(pump_energy, in_keys=["observation"], out_keys=["action"])


def test_start_states_are_uniform_in_gymnasiums_range_with_zero_velocity():
    start = BatchedMountainCarEnv(4096, seed=0).reset()["observation"]
    position, velocity = start.unbind(-1)
    assert position.min() >= -0.6 and position.max() <= -0.4
    assert position.min() < -0.599 and position.max() > -0.401
    assert position.mean().item() == pytest.approx(-0.5, abs=0.005)
    assert (velocity == 0).all()


def test_trajectories_equal_gymnasiums_including_termination_and_truncation():
    """Same start state, same actions: pumping ends at the flag, random and idle cars are truncated at 200."""
    env = BatchedMountainCarEnv(3, seed=1)
    td = env.reset()
    starts = env.physical_state.clone()
    actions = torch.randint(3, (200, 3), generator=torch.Generator().manual_seed(0))
    actions[:, 1] = 1  # idle
    ours, done_at = [], [None] * 3
    for t in range(200):
        actions[t, 2] = pump_energy(td["observation"][2]).argmax()
        td = env.step(td.set("action", torch.nn.functional.one_hot(actions[t], 3)))
        ours.append(td["next"].clone())
        td = td["next"]
    ours = torch.stack(ours, 1)
    for i in range(3):
        gym_env = gym.make("MountainCar-v0")
        gym_env.reset(seed=0)
        gym_env.unwrapped.state = starts[i].numpy()
        for t in range(200):
            observation, reward, terminated, truncated, _ = gym_env.step(int(actions[t, i]))
            step = ours[i, t]
            torch.testing.assert_close(step["observation"], torch.from_numpy(observation), atol=1e-5, rtol=0)
            assert (step["reward"].item(), step["terminated"].item(), step["truncated"].item()) == (
                reward,
                terminated,
                truncated,
            )
            if terminated or truncated:
                done_at[i] = t + 1
                break
    assert done_at[0] == done_at[1] == 200
    assert ours[:2, -1]["truncated"].all() and not ours[:2]["terminated"].any()
    assert done_at[2] < 200 and ours[2, done_at[2] - 1]["terminated"].item()


def test_partial_reset_restarts_only_the_finished_envs():
    env = BatchedMountainCarEnv(2, max_episode_steps=3, seed=0)
    td = env.reset()
    for _ in range(3):
        td = env.step(td.set("action", torch.nn.functional.one_hot(torch.tensor([2, 2]), 3)))["next"]
    before = td["observation"].clone()
    td.set("_reset", torch.tensor([[True], [False]]))
    after = env.reset(td)["observation"]
    assert after[0, 1] == 0 and -0.6 <= after[0, 0] <= -0.4
    torch.testing.assert_close(after[1], before[1])
    assert env.elapsed_steps.tolist() == [0, 3]


def test_collector_auto_resets_each_env_when_it_is_done():
    env = make_env("mountaincar", num_envs=4, seed=0)
    collector = Collector(env, PUMP, frames_per_batch=100, total_frames=500)
    data = torch.cat([batch for batch in collector], 1)  # (4 envs, 125 steps)
    collector.shutdown()
    assert data.shape == (4, 125)
    done = data["next", "done"].squeeze(-1)
    step_count = data["step_count"].squeeze(-1)
    assert done.any(1).all(), "every env reaches the flag within 125 steps"
    after_done = torch.zeros_like(done)
    after_done[:, 1:] = done[:, :-1]
    assert (step_count[after_done] == 0).all() and data["is_init"].squeeze(-1)[after_done].all()
    restarted = data["observation"][after_done]
    assert (restarted[:, 1] == 0).all() and ((restarted[:, 0] >= -0.6) & (restarted[:, 0] <= -0.4)).all()
    continuing = ~after_done[:, 1:]
    assert (step_count[:, 1:][continuing] == step_count[:, :-1][continuing] + 1).all()


def test_collector_truncates_long_episodes():
    env = BatchedMountainCarEnv(2, max_episode_steps=30, seed=0)
    collector = Collector(env, None, frames_per_batch=100, total_frames=100)
    data = next(iter(collector))
    collector.shutdown()
    truncated = data["next", "truncated"].squeeze(-1)
    assert truncated.nonzero()[:, 1].tolist() == [29, 29]


def test_make_env_batches_other_tasks_serially_and_rejects_bad_requests():
    assert isinstance(make_env("mountaincar").base_env, GymWrapper)  # single env unchanged
    assert isinstance(make_env("mountaincar", num_envs=3, backend="gym").base_env, GymBatchEnv)
    lunarlander = make_env("lunarlander", num_envs=2, seed=0)  # Box2D: no torch implementation
    assert isinstance(lunarlander.base_env, GymBatchEnv) and lunarlander.rollout(3).shape == (2, 3)
    with pytest.raises(ValueError, match="num_envs must be a positive integer"):
        make_env("mountaincar", num_envs=0)
    with pytest.raises(ValueError, match="No torch implementation of LunarLander-v3"):
        make_env("lunarlander", num_envs=2, backend="torch")
    with pytest.raises(ValueError, match="backend must be"):
        make_env("mountaincar", backend="jax")


def test_model_based_exploration_keeps_one_window_per_env_in_a_collector():
    num_envs = 4
    env = make_env("mountaincar", num_envs=num_envs, seed=0)
    spec = env.action_spec
    actor = QValueActor(MLP(out_features=3, num_cells=[48]), spec=spec, in_keys=["observation"])
    density = RollingGaussianDensity(2, window=50, batch_shape=(num_envs,))
    planner = NoveltyPlanner(DynamicsModel(2, spec), density, spec)
    policy = ModelBasedExplorationPolicy(actor, planner, eps_init=1.0, eps_end=1.0)
    collector = Collector(env, policy, frames_per_batch=4 * 30, total_frames=4 * 90)
    observations = torch.cat([batch["observation"] for batch in collector], 1)
    collector.shutdown()
    assert observations.shape == (num_envs, 90, 2)
    torch.testing.assert_close(density.window_states(), observations[:, -50:])
    assert np.isfinite(density.score(observations[:, -1]).numpy()).all()


def test_a_batched_rollout_gives_one_episode_per_env_even_when_they_end_at_different_times():
    from tensordict.nn import TensorDictModule

    from torchrl_mbe.envs import first_episodes, make_env

    def push_along_velocity(observation: torch.Tensor) -> torch.Tensor:  # pumps energy: reaches the flag in ~100 steps
        return torch.nn.functional.one_hot(torch.where(observation[..., 1] >= 0, 2, 0), 3)

    env = make_env("mountaincar", num_envs=8, seed=3)
    policy = TensorDictModule(push_along_velocity, in_keys=["observation"], out_keys=["action"])
    rollout = env.rollout(1000, policy, break_when_any_done=False, break_when_all_done=True)
    episodes = first_episodes(rollout)
    lengths = [episode.length for episode in episodes]
    assert len(episodes) == 8 and all(episode.terminated for episode in episodes)
    assert len(set(lengths)) > 1 and max(lengths) == rollout.shape[-1] < 200  # the last env to finish ends the rollout
    assert [episode.episode_return for episode in episodes] == [-float(n) for n in lengths]
