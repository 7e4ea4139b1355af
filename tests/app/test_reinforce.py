from __future__ import annotations

import json
import os
import signal

import numpy as np
import pytest
import torch
from tensordict import TensorDict
from torch import nn
from torchrl.data import OneHot
from torchrl.modules import MLP

import torchrl_mbe.app.run as run_module
from torchrl_mbe.app import ConfigError, train
from torchrl_mbe.app.reinforce import build_reinforce_agent, make_policy_actor, write_advantage
from torchrl_mbe.envs import make_env
from torchrl_mbe.rundir import CHECKPOINT, tables


@pytest.fixture
def compose_reinforce(compose_config):
    return lambda *overrides: compose_config("algo=reinforce", *overrides)


def test_reinforce_trains_and_writes_the_same_run_files_as_dqn(tmp_path, read_table, compose_reinforce):
    cfg = compose_reinforce("env=mountaincar", "train.max_frames=400", "eval.episodes=1", "eval.every_frames=200")
    summary = train(cfg, tmp_path)
    assert summary["method"] == "reinforce" and summary["env"] == "MountainCar-v0"
    assert summary["frames"] == 400 and summary["episodes"] == 2  # MountainCar's time limit: 200 steps
    assert json.loads((tmp_path / "summary.json").read_text()) == summary
    episodes = read_table(tmp_path, "episodes")
    assert tuple(episodes[0]) == tables()["episodes"]
    assert [(row["episode"], row["frames"], float(row["eps"])) for row in episodes] == [
        ("1", "200", 0.0),
        ("2", "400", 0.0),
    ]
    assert [row["frames"] for row in read_table(tmp_path, "evaluations")] == ["200", "400", "400"]  # periodic, final
    actor_state = torch.load(tmp_path / CHECKPOINT, weights_only=True)["agent"]["actor"]
    biases = [value for name, value in actor_state.items() if name.endswith("bias")]
    assert len(biases) == 2 and not all(torch.all(bias == 0.1) for bias in biases)  # the policy was updated


def test_the_policy_network_starts_as_in_the_appendix(compose_reinforce):
    cfg = compose_reinforce("env=cartpole")
    agent = build_reinforce_agent(cfg, make_env("cartpole"))
    assert agent.gamma == 0.995 and agent.step.optimizer.defaults["lr"] == 0.02
    assert isinstance(agent.step.optimizer, torch.optim.Adam)
    network = agent.actor.module[0].module
    assert isinstance(network, MLP) and [type(layer) for layer in network] == [nn.Linear, nn.Tanh, nn.Linear]
    assert (network[0].in_features, network[0].out_features, network[2].out_features) == (4, 10, 2)

    wide = make_policy_actor(2000, OneHot(3), [10]).module[0].module  # enough weights to measure their spread
    for layer in (wide[0], wide[2]):
        assert torch.all(layer.bias == 0.1)
    assert wide[0].weight.mean().item() == pytest.approx(0.0, abs=0.01)
    assert wide[0].weight.std().item() == pytest.approx(0.3, abs=0.01)


def test_returns_are_discounted_then_normalized_over_the_episode():
    rewards, gamma = [1.0, -2.0, 0.5, 3.0], 0.9
    returns = [sum(gamma**k * r for k, r in enumerate(rewards[t:])) for t in range(len(rewards))]
    expected = (np.array(returns) - np.mean(returns)) / np.std(returns)
    episode = write_advantage(_episode(rewards), gamma)
    assert episode["value_target"].flatten().tolist() == pytest.approx(returns, rel=1e-6)
    assert episode["advantage"].flatten().tolist() == pytest.approx(expected.tolist(), rel=1e-5)
    assert write_advantage(_episode([5.0]), gamma)["advantage"].item() == 0.0  # one step: nothing to centre


def test_the_loss_is_the_reinforce_gradient_of_the_normalized_returns(compose_reinforce):
    env = make_env("cartpole")
    agent = build_reinforce_agent(compose_reinforce("env=cartpole"), env)
    episode = _episode([1.0, 1.0, 1.0, 0.0], observation=torch.randn(4, 4), action=env.action_spec.rand((4,)))
    loss = agent.loss(write_advantage(episode, agent.gamma))["loss_actor"]
    log_prob = agent.actor.get_dist(episode).log_prob(episode["action"])
    assert loss.item() == pytest.approx(-(log_prob * episode["advantage"].flatten()).mean().item(), rel=1e-5)
    assert set(agent.loss.parameters()) == set(agent.actor.parameters())  # the zero baseline has nothing to train


def test_reinforce_learns_to_balance_cartpole_within_3000_frames(tmp_path, read_table, compose_reinforce):
    cfg = compose_reinforce("env=cartpole", "train.max_frames=3000", "train.episodes=1000", "eval.final_episodes=0")
    train(cfg, tmp_path)
    lengths = [int(row["length"]) for row in read_table(tmp_path, "episodes")]
    assert np.mean(lengths[-10:]) > 2 * np.mean(lengths[:10])  # seeds 0-9 all tried: 2.8x to 7x


def test_ctrl_c_then_resume_continues_a_reinforce_run(tmp_path, monkeypatch, read_table, compose_reinforce):
    cfg = compose_reinforce("env=mountaincar", "train.max_frames=800", "eval.final_episodes=0")
    original = run_module._record_episodes

    def press_ctrl_c_in_the_second_episode(run, batch, eps):
        if run.progress.episodes == 1:
            os.kill(os.getpid(), signal.SIGINT)
        return original(run, batch, eps)

    monkeypatch.setattr(run_module, "_record_episodes", press_ctrl_c_in_the_second_episode)
    with pytest.raises(SystemExit, match="Interrupted at 400 frames"):
        train(cfg, tmp_path)
    saved = torch.load(tmp_path / CHECKPOINT, weights_only=True)
    assert saved["members"][0]["progress"]["episodes"] == 2 and "replay_buffer" not in saved["kept"]

    monkeypatch.setattr(run_module, "_record_episodes", original)
    cfg.resume = True
    summary = train(cfg, tmp_path)
    assert (summary["frames"], summary["episodes"]) == (800, 4)
    assert [row["episode"] for row in read_table(tmp_path, "episodes")] == ["1", "2", "3", "4"]


@pytest.mark.parametrize(
    "overrides, message",
    [
        (["env.num_envs=2"], "env.num_envs=2: algo=reinforce plays one episode at a time"),
        (["algo.lr=-0.1"], r"algo.lr=-0.1: expected a number > 0"),
        (["algo.num_cells=[]"], r"algo.num_cells=\[\]: expected a non-empty list"),
    ],
)
def test_bad_reinforce_config_values_get_one_clear_error(tmp_path, overrides, message, compose_reinforce):
    with pytest.raises(ConfigError, match=message):
        train(compose_reinforce(*overrides), tmp_path)


def test_train_py_runs_reinforce(tmp_path, run_app):
    result = run_app("algo=reinforce", "env=mountaincar", "train.max_frames=200", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    (summary_path,) = (tmp_path / "runs").rglob("summary.json")
    assert json.loads(summary_path.read_text())["method"] == "reinforce"


def _episode(rewards: list[float], **entries: torch.Tensor) -> TensorDict:
    done = torch.zeros(len(rewards), 1, dtype=torch.bool)
    done[-1] = True
    return TensorDict(
        {**entries, "next": {"reward": torch.tensor(rewards).unsqueeze(-1), "done": done}}, [len(rewards)]
    )
