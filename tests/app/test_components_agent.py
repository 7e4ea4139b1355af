"""docs/usage.md's MountainCar agent, built from the components, is the one ``python train.py env=mountaincar`` trains."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import torch

from torchrl_mbe import make_env
from torchrl_mbe.app.dqn import build_dqn_agent

SECTION = "### The app's MountainCar agent from the components\n"


@pytest.fixture(scope="module")
def block() -> dict:
    """The names the page's block defines, after it has run as written."""
    usage = (Path(__file__).resolve().parents[2] / "docs" / "usage.md").read_text()
    (code,) = re.findall(r"```python\n(.*?)```", usage.split(SECTION, 1)[1].split("\n### ", 1)[0], flags=re.DOTALL)
    namespace = {"__name__": "__usage__"}
    exec(compile(code, "docs/usage.md", "exec"), namespace)
    return namespace


@pytest.fixture
def app(compose_default):
    cfg = compose_default("env=mountaincar")
    return cfg, build_dqn_agent(cfg, make_env("mountaincar", num_envs=cfg.env.num_envs, seed=0))


def shapes(module: torch.nn.Module) -> dict:
    return {
        name: tuple(tensor.shape) for name, tensor in module.state_dict().items() if isinstance(tensor, torch.Tensor)
    }


def test_the_blocks_networks_are_the_apps(block, app):
    _, agent = app
    assert shapes(block["q_actor"]) == shapes(agent.actor)  # 256x256 on standardized inputs
    assert shapes(block["dynamics"]) == shapes(agent.explorer.policy.planner.dynamics)
    assert block["q_input_norm"].scale.ne(1).any()  # fitted once learning started, as the app fits it
    assert block["dynamics"].normalization_fitted


def test_the_blocks_losses_schedules_and_explorer_are_the_apps(block, app):
    cfg, agent = app
    ours, theirs = block["dqn_loss"], agent.q_loss
    assert (ours.loss_function, ours.double_dqn, ours.delay_value) == (
        theirs.loss_function,
        theirs.double_dqn,
        theirs.delay_value,
    )
    assert ours.value_estimator.gamma == theirs.value_estimator.gamma == block["n_step"].gamma
    assert block["n_step"].n_steps == cfg.algo.n_steps
    assert block["target_updater"].value_network_update_interval == agent.target_updater.value_network_update_interval
    assert block["q_optim"].defaults["lr"] == agent.q_step.optimizer.defaults["lr"]
    assert block["dynamics_optim"].defaults["lr"] == agent.explorer.training.step.optimizer.defaults["lr"]
    assert block["buffer"].sample().numel() == cfg.algo.batch_size == cfg.dynamics.batch_size
    assert block["buffer"].storage.max_size == cfg.buffer.size
    assert (block["q_learning_starts"], block["dynamics_learning_starts"]) == (
        cfg.algo.learning_starts,
        cfg.dynamics.learning_starts,
    )
    assert block["updates_per_frame"] == cfg.algo.updates_per_frame == cfg.dynamics.updates_per_frame
    assert block["batch"].shape == (cfg.env.num_envs, cfg.collector.frames_per_batch // cfg.env.num_envs)
    policy, app_policy = block["policy"], agent.explorer.policy
    assert (policy.eps_init, policy.eps_end, policy.annealing_num_steps) == (
        app_policy.eps_init,
        app_policy.eps_end,
        app_policy.annealing_num_steps,
    )
    novelty, app_novelty = policy.planner.novelty, app_policy.planner.novelty
    assert type(novelty) is type(app_novelty) and novelty.window == app_novelty.window == cfg.exploration.window
