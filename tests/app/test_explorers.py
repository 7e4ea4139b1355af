"""The explorer registry: one entry per ``exploration=`` option, one shape for the loop, a new explorer in one place."""

from __future__ import annotations

from dataclasses import dataclass

import pytest
from tensordict.nn import TensorDictModuleBase, TensorDictSequential
from torchrl.collectors import Collector

from torchrl_mbe.app import ConfigError, register_configs, train
from torchrl_mbe.app.dqn import build_dqn_agent
from torchrl_mbe.app.explorers import EXPLORERS, EGreedyExplorer, ExplorationConfig, Explorer, ExplorerContext
from torchrl_mbe.app.replay import ReplayTransitions, make_replay_buffer
from torchrl_mbe.app.settings import PROBABILITY, setting
from torchrl_mbe.envs import make_env
from torchrl_mbe.modules import AnnealedEGreedyModule


@pytest.mark.parametrize("name", sorted(EXPLORERS))
def test_every_explorer_gives_the_loop_the_same_shape_and_its_state_survives_a_checkpoint(name, compose_config):
    cfg = compose_config(f"exploration={name}", "algo.batch_size=32", "dynamics.batch_size=32")
    env = make_env("mountaincar", num_envs=4, seed=0)
    agent = build_dqn_agent(cfg, env)
    explorer = agent.explorer
    assert isinstance(explorer, EXPLORERS[name]) and isinstance(explorer.policy, TensorDictModuleBase)
    batch = next(iter(Collector(env, explorer.policy, frames_per_batch=64, total_frames=-1)))
    buffer = make_replay_buffer(cfg.buffer, "cpu")
    buffer.extend(
        ReplayTransitions(1, 0.99, intrinsic_coef=explorer.intrinsic_coef, extra_keys=explorer.stored_keys)(batch)
    )
    eps_before = agent.eps
    agent.learn(batch, buffer, frames=cfg.algo.learning_starts + 64)  # past learning_starts: Q updates run
    assert agent.q_updates == 16 and isinstance(agent.eps, float) and agent.eps <= eps_before
    assert set(agent.summary_fields()) <= {"q_updates", "dynamics_updates"}
    rebuilt = build_dqn_agent(cfg, make_env("mountaincar", num_envs=4, seed=0))
    rebuilt.load_state_dict(agent.state_dict())
    assert rebuilt.summary_fields() == agent.summary_fields() and rebuilt.eps == agent.eps
    assert rebuilt.explorer.state_dict().keys() == explorer.state_dict().keys()


def test_the_diagonal_explorers_variance_floor_and_addition_reach_its_density_and_the_raw_model_its_planner(
    compose_config,
):
    cfg = compose_config(
        "exploration=diagonal",
        "exploration.min_variance=1e-3",
        "exploration.added_variance=1e-2",
        "dynamics.normalize=false",
        "dynamics.prior_scale=25",
        "dynamics.prior_num_cells=[32]",
    )
    agent = build_dqn_agent(cfg, make_env("mountaincar", num_envs=4, seed=0))
    planner = agent.explorer.policy.planner
    assert planner.novelty.min_variance == 1e-3 and planner.novelty.added_variance == 1e-2
    assert planner.dynamics.normalize is False and planner.dynamics.normalization_fitted
    assert planner.dynamics.prior_scale == 25 and planner.dynamics.prior[0].out_features == 32


def test_every_explorer_is_a_hydra_option_of_its_own_name(compose_config):
    for name, explorer in EXPLORERS.items():
        assert explorer.schema.name == name and compose_config(f"exploration={name}").exploration.name == name


def test_an_unknown_explorer_is_refused_while_composing(tmp_path, run_app):
    result = run_app("exploration=softmax", f"hydra.run.dir={tmp_path}/run", cwd=tmp_path)
    assert result.returncode != 0 and "Could not find 'exploration/softmax'" in result.stderr
    assert "gaussian" in result.stderr  # Hydra lists the options there are
    assert not (tmp_path / "run" / "checkpoint.pt").exists()


@dataclass
class ConstantEGreedyExploration(ExplorationConfig):
    name: str = "constant"
    eps: float = setting(0.1, PROBABILITY)


class ConstantEGreedyExplorer(EGreedyExplorer):
    """The worked example of docs/architecture.md: e-greedy at a fixed rate, which logs how many frames it saw."""

    schema = ConstantEGreedyExploration
    log_columns = ("frames_seen",)
    counters = ("batches_seen",)

    def __init__(self, policy, eps_module) -> None:
        super().__init__(policy, eps_module)
        self.frames_seen = self.batches_seen = 0

    def observe(self, batch) -> None:
        self.frames_seen += batch.numel()
        self.batches_seen += 1

    def log_fields(self) -> dict[str, float | None]:
        return {"frames_seen": self.frames_seen}

    def summary_fields(self) -> dict[str, int]:
        return {"batches_seen": self.batches_seen}

    @classmethod
    def build(cls, context: ExplorerContext) -> Explorer:
        eps = context.cfg.exploration.eps
        egreedy = AnnealedEGreedyModule(context.action_spec, eps, eps, 1, device=context.action_spec.device)
        return cls(TensorDictSequential(context.actor, egreedy), egreedy)


def test_a_new_explorer_is_one_class_and_one_registry_entry(tmp_path, monkeypatch, compose_config, read_table):
    monkeypatch.setitem(EXPLORERS, "constant", ConstantEGreedyExplorer)
    register_configs()
    summary = train(
        compose_config("exploration=constant", "exploration.eps=0.3", "logger.log_every_updates=10"), tmp_path
    )
    assert summary["method"] == "dqn+constant" and summary["q_updates"] > 0
    assert {float(row["eps"]) for row in read_table(tmp_path, "episodes")} == {0.3}
    updates = read_table(tmp_path, "updates")
    assert updates and all(
        int(row["frames_seen"]) == int(row["frames"]) for row in updates
    )  # its own column, declared once
    assert summary["batches_seen"] == summary["frames"] // 16 and summary["dynamics_updates"] == 0
    with pytest.raises(ConfigError, match="exploration.eps=1.5: expected a number in"):
        train(compose_config("exploration=constant", "exploration.eps=1.5"), tmp_path / "bad")
