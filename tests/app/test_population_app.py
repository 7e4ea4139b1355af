"""``population=M``: M agents in one process, each member's run directory a single run's, members that never mix."""

from __future__ import annotations

import csv
import json
from functools import partial

import pytest
import torch
from tensordict import TensorDict
from torchrl.collectors import Collector

from torchrl_mbe.app import ConfigError, check_config, train
from torchrl_mbe.app.checkpoints import load_safely
from torchrl_mbe.app.dqn import DQNTraining, build_dqn_agent, make_q_actor
from torchrl_mbe.app.environments import make_run_env
from torchrl_mbe.app.explorers import RNDExplorer, explorer_of, logged_columns
from torchrl_mbe.app.identity import config_id
from torchrl_mbe.app.population import StopOnInterrupt, open_population
from torchrl_mbe.app.replay import PopulationReplayBuffer, ReplayTransitions
from torchrl_mbe.app.rollout import CollectorState, EnvState
from torchrl_mbe.modules import Standardize
from torchrl_mbe.report.runs import load_runs
from torchrl_mbe.rundir import BEST_POLICY, CHECKPOINT, SUMMARY, table_file, tables

SMALL = ("algo.num_cells=[16,16]", "dynamics.num_cells=[16]", "algo.batch_size=32", "dynamics.batch_size=32")


def test_a_population_writes_one_single_run_directory_per_member(tmp_path, compose_config):
    overrides = ("population=3", "seed=4", "env.num_envs=2", "eval.episodes=2", "eval.every_frames=128", *SMALL)
    summary = train(compose_config(*overrides), tmp_path / "population")
    assert [member["seed"] for member in summary["members"]] == [4, 5, 6] and summary["population"] == 3
    single = compose_config(*overrides[1:], "seed=5")
    for seed in (4, 5, 6):
        member = tmp_path / "population" / f"seed{seed}"
        written = json.loads((member / SUMMARY).read_text())
        assert written["seed"] == seed and written["config_id"] == config_id(single)  # grouped with single runs of it
        assert written["frames"] == 304 and written["q_updates"] > 0 and written["final_eval_return"] is not None
        for table, columns in tables(logged_columns()).items():
            with (member / table_file(table)).open() as handle:
                assert tuple(csv.DictReader(handle).fieldnames) == columns
        with (member / table_file("episodes")).open() as handle:
            assert len(list(csv.DictReader(handle))) == written["episodes"]
    runs = load_runs(tmp_path)
    assert sorted(run.seed for run in runs) == [4, 5, 6] and {run.method for run in runs} == {"dqn+gaussian"}


def test_a_gymnasium_env_trains_as_a_population_each_member_evaluated_in_its_own_copies(tmp_path, compose_config):
    overrides = (
        "env=lunarlander",
        "population=2",
        "env.num_envs=2",
        "train.max_frames=256",
        "eval.every_frames=128",
        "eval.episodes=2",
    )
    train(
        compose_config(
            *overrides, "eval.final_episodes=2", "algo.learning_starts=64", "dynamics.learning_starts=64", *SMALL
        ),
        tmp_path,
    )
    evaluations = {}
    for seed in (0, 1):
        summary = json.loads((tmp_path / f"seed{seed}" / SUMMARY).read_text())
        assert summary["env"] == "LunarLander-v3" and summary["frames"] == 256 and summary["q_updates"] > 0
        with (tmp_path / f"seed{seed}" / table_file("evaluations")).open() as handle:
            evaluations[seed] = [float(row["eval_return_mean"]) for row in csv.DictReader(handle)]
    assert (
        len(evaluations[0]) == 3 and evaluations[0] != evaluations[1]
    )  # two periodic and the final, each member's own


@pytest.mark.parametrize("exploration", ["gaussian", "bootstrap"])
def test_a_members_best_policy_is_a_single_actors_and_acts_as_the_member_did(exploration, tmp_path, compose_config):
    overrides = (
        "population=2",
        f"exploration={exploration}",
        "env.num_envs=2",
        "eval.episodes=2",
        "eval.every_frames=128",
    )
    cfg = compose_config(*overrides, *SMALL)
    train(cfg, tmp_path)
    env = make_run_env(cfg, num_envs=1, seed=0)
    observation_size = env.observation_spec_unbatched["observation"].shape[-1]
    policies = []
    for seed in (0, 1):
        actor = make_q_actor(
            observation_size,
            env.action_spec_unbatched,
            cfg.algo.num_cells,
            torch.device("cpu"),
            input_norm=Standardize(observation_size),
            q_network=explorer_of(cfg.exploration).q_network(cfg),  # a Bootstrapped DQN's ensemble, else plain
        )
        actor.load_state_dict(
            load_safely(tmp_path / f"seed{seed}" / BEST_POLICY)["actor"]
        )  # strict: a single actor's keys
        policies.append(actor)
    states = TensorDict(observation=torch.randn(64, observation_size), batch_size=[64])
    values = [policy(states.clone())["action_value"] for policy in policies]
    assert not torch.allclose(values[0], values[1])  # each member's own network


@pytest.mark.parametrize("exploration", ["gaussian", "egreedy", "noisy", "rnd"])
def test_changing_one_members_data_and_parameters_leaves_every_other_members_updates_unchanged(
    exploration, compose_config
):
    clipping = ("algo.max_grad_norm=0.01", "dynamics.max_grad_norm=0.01")  # every member's gradient clipped
    cfg = compose_config("population=3", f"exploration={exploration}", "env.num_envs=4", *clipping, *SMALL)
    trained = [_learn_once(cfg, perturb_member=None), _learn_once(cfg, perturb_member=1)]
    for (name, untouched), (_, perturbed) in zip(*trained):
        if "epsilon" not in name:  # NoisyNet's noise is drawn, not learned: the same draws in both
            assert not torch.equal(untouched[1], perturbed[1]), name  # the perturbed member's changed
        for member in (0, 2):
            assert torch.equal(untouched[member], perturbed[member]), f"{name}, member {member}"


def _learn_once(cfg, *, perturb_member: int | None) -> list[tuple[str, torch.Tensor]]:
    """Every parameter and statistic (stacked ``[M, ...]``) after one round of updates, with one member's data and weights changed."""
    torch.manual_seed(0)
    env = make_run_env(cfg, num_envs=cfg.env.num_envs, seed=0)
    agent = build_dqn_agent(cfg, env)
    batch = next(iter(Collector(env, agent.explorer.policy, frames_per_batch=128 * 3, total_frames=-1)))
    if perturb_member is not None:
        batch["observation"][:, perturb_member] *= (
            1.5  # a scale, not only a shift: the input statistics' spread changes too
        )
        batch["next", "observation"][:, perturb_member] -= 0.5
        with torch.no_grad():
            for parameter in agent.explorer.policy.parameters():
                parameter[perturb_member] += 0.1
    buffer = PopulationReplayBuffer(1000, 3)
    buffer.extend(ReplayTransitions(1, 0.99, intrinsic_coef=agent.explorer.intrinsic_coef, num_members=3)(batch))
    torch.manual_seed(1)  # the same sampling draws in both
    agent.learn(batch, buffer, frames=max(cfg.algo.learning_starts, cfg.dynamics.learning_starts) + 128)
    assert agent.q_updates > 0 and agent.summary_fields().get("dynamics_updates", 1) > 0
    state = agent.explorer.policy.state_dict()
    target = agent.q_loss.target_value_network_params.flatten_keys(".")
    # RND's predictor learns from the sampled batch (its target never learns)
    predictor = agent.explorer.rnd.predictor_network.state_dict() if isinstance(agent.explorer, RNDExplorer) else {}
    stacked = [
        *state.items(),
        *target.items(),
        *predictor.items(),
    ]  # the windows, (num_envs, M, ...), are filled while collecting: equal
    return [
        (name, value)
        for name, value in stacked
        if isinstance(value, torch.Tensor) and not value.is_meta and value.ndim and value.shape[0] == 3
    ]


def test_a_noisy_populations_q_update_resamples_every_members_noise(compose_config):
    cfg = compose_config("population=3", "exploration=noisy", "env.num_envs=2", *SMALL)
    agent = build_dqn_agent(cfg, make_run_env(cfg, num_envs=2, seed=0))
    noise = lambda: agent.actor.state_dict()["module.0.module.1.params.0.weight_epsilon"].clone()
    before = noise()
    agent.explorer.after_q_update(TensorDict())
    after = noise()
    assert all(not torch.equal(before[member], after[member]) for member in range(3))


@pytest.mark.parametrize(
    ("overrides", "named"),
    [
        (("population=0",), "population=0: expected a positive integer"),
        (("population=2", "buffer=prioritized"), "use buffer=uniform or population=1"),
        (("population=2", "algo=reinforce"), "only algo=dqn trains populations"),
    ],
)
def test_a_population_it_cannot_train_is_refused_in_one_line_naming_the_setting(overrides, named, compose_config):
    with pytest.raises(ConfigError) as refused:
        check_config(compose_config(*overrides))
    assert named in str(refused.value) and "\n" not in str(refused.value)


@pytest.mark.parametrize("exploration", ["gaussian", "rnd"])
def test_a_population_resumes_where_it_stopped(exploration, tmp_path, compose_config):
    # No final evaluation: at the first budget it would draw from torch's generator, which a run that never stopped does not.
    overrides = (
        "population=2",
        f"exploration={exploration}",
        "env.num_envs=2",
        "eval.episodes=0",
        "eval.final_episodes=0",
        "train.checkpoint_every_frames=128",
        *SMALL,
    )
    whole = train(compose_config(*overrides), tmp_path / "whole")
    train(compose_config(*overrides, "train.max_frames=160"), tmp_path / "resumed")
    resumed = train(compose_config(*overrides, "resume=true"), tmp_path / "resumed")
    for before, after in zip(whole["members"], resumed["members"]):
        assert after["frames"] == before["frames"] and after["episodes"] == before["episodes"]
    for seed in (0, 1):
        episodes = [
            (tmp_path / run / f"seed{seed}" / table_file("episodes")).read_text() for run in ("whole", "resumed")
        ]
        columns = [[line.split(",")[:5] for line in text.splitlines()] for text in episodes]
        assert columns[0] == columns[1]  # the same episodes, wall times aside
    agents = [load_safely(tmp_path / run / CHECKPOINT)["agent"] for run in ("whole", "resumed")]
    torch.testing.assert_close(
        agents[1], agents[0], rtol=0, atol=0
    )  # every network, statistic and optimizer, bit for bit


def test_a_population_split_into_processes_writes_every_members_run_and_resumes_each_part(tmp_path, compose_config):
    overrides = ("population=3", "processes=2", "eval.episodes=0", "train.checkpoint_every_frames=128", *SMALL)
    first = train(compose_config(*overrides, "train.max_frames=160"), tmp_path)
    assert [member["frames"] for member in first["members"]] == [160, 160, 160]
    assert first["run_dirs"] == [
        str(tmp_path / "seeds0-1" / "seed0"),
        str(tmp_path / "seeds0-1" / "seed1"),
        str(tmp_path / "seed2"),
    ]
    resumed = train(compose_config(*overrides, "resume=true"), tmp_path)
    assert [member["seed"] for member in resumed["members"]] == [0, 1, 2]
    assert all(member["frames"] == 300 + 4 for member in resumed["members"])  # 19 batches of 16 frames
    assert json.loads((tmp_path / "seed2" / SUMMARY).read_text())["frames"] == resumed["members"][2]["frames"]


def test_the_parts_of_a_population_record_the_command_that_launched_them(tmp_path, run_app):
    result = run_app(
        "population=2", "processes=2", "algo.num_cells=[16,16]", f"hydra.run.dir={tmp_path}/run", cwd=tmp_path
    )
    assert result.returncode == 0, result.stderr
    assert "population=2 in 2 processes side by side" in result.stdout + result.stderr
    for seed in (0, 1):
        record = json.loads((tmp_path / "run" / f"seed{seed}" / SUMMARY).read_text())["record"]
        assert record["command"].startswith("python train.py population=2 processes=2")


@pytest.mark.parametrize(
    ("env", "exploration"),
    [("mountaincar", "gaussian"), ("mountaincar", "rnd"), ("mountaincar", "bootstrap"), ("lunarlander", "noisy")],
)
def test_a_stopped_member_leaves_the_batch_and_the_others_go_on_from_their_own_state(
    env, exploration, tmp_path, compose_config
):
    starts = ("algo.learning_starts=32", "dynamics.learning_starts=32", "algo.n_steps=3")
    cfg = compose_config(
        f"env={env}",
        "population=3",
        f"exploration={exploration}",
        "env.num_envs=2",
        "eval.episodes=2",
        "eval.final_episodes=0",
        *starts,
        *SMALL,
    )
    torch.manual_seed(0)
    training = DQNTraining(cfg, 3)
    population = open_population(cfg, tmp_path, training.agent)
    for name, part in training.parts().items():
        population.keep(name, part)
    for _ in range(3):  # every part holds state: windows, replay rows, Adam's moments, an episode under way
        batch = next(training.batches)
        stored = training.transitions(batch)
        if stored is not None:
            training.replay_buffer.extend(stored)
        population.record(batch)
        training.agent.learn(batch, training.replay_buffer, population.frames)
    population.runs[1].progress.episodes = cfg.train.episodes  # member 1 spent its budget
    with StopOnInterrupt() as interrupt:
        assert population.training(interrupt) and population.holds_stopped_members()
    copies = training.collector.env.base_env.copies() if env == "lunarlander" else None
    stayed = population.leave_batch(partial(DQNTraining, cfg))  # the parts left behind are untouched
    assert population.in_batch == [0, 2] and stayed.collector.env.batch_size == (2, 2)
    if copies is not None:  # gymnasium copies go on mid-episode: members 0 and 2 of each row
        assert stayed.collector.env.base_env.copies() == [copies[index] for index in (0, 2, 3, 5)]
    torch.manual_seed(1)
    sample = training.replay_buffer.sample(16).exclude("index")
    before, after = _what_members_see(training, sample), _what_members_see(stayed, sample[:, [0, 2]])
    assert before.keys() == after.keys()
    for name, seen in after.items():
        torch.testing.assert_close(seen, before[name][:, [0, 2]], rtol=0, atol=0, msg=name)


def _what_members_see(training: DQNTraining, sample: TensorDict) -> dict[str, torch.Tensor]:
    """Each member's view (member dimension 1): its replay rows, the step it goes on from, its greedy Q-values, and one Q step's losses and Q-values."""
    agent = training.agent
    env_state = EnvState(training.collector.env).state_dict()  # a torch-batched env's: (num_envs, M, ...)
    carrier = CollectorState(training.collector).handover_state()["carrier"]
    observation = TensorDict(observation=carrier["observation"].clone(), batch_size=carrier["observation"].shape[:-1])
    views = {
        **{f"env {name}": state for name, state in env_state.items() if isinstance(state, torch.Tensor)},
        "replay rows": training.replay_buffer[: len(training.replay_buffer)]["observation"],
        "step count": carrier["step_count"],
        "q-values": agent.actor(observation.clone())["action_value"],
    }
    if hasattr(agent.explorer.policy, "planner"):
        views["novelty scores"] = agent.explorer.policy.planner.action_scores(observation["observation"])
    losses = agent.q_step(sample.clone())  # the loss reads the target network; the step, Adam's moments
    views["q loss"] = torch.tensor(losses).view(1, -1)
    views["q-values after a step"] = agent.actor(observation.clone())["action_value"]
    return {name: view.detach() for name, view in views.items()}


# Interrupted before the first member leaves the batch and after it (the test checks that it leaves between the two).
@pytest.mark.parametrize("interrupted_at", [320, 544])
def test_a_population_whose_members_leave_the_batch_resumes_where_it_stopped(interrupted_at, tmp_path, compose_config):
    overrides = (
        "env=cartpole",
        "population=3",
        "env.num_envs=2",
        "train.episodes=40",  # the members' episodes differ in length: they stop one after another
        "train.max_frames=null",
        "eval.episodes=0",
        "eval.final_episodes=0",
        "train.checkpoint_every_frames=128",
        *SMALL,
    )
    whole = train(compose_config(*overrides), tmp_path / "whole")
    stopped_at = [member["frames"] for member in whole["members"]]
    first, second, _ = sorted(stopped_at)
    assert 320 < first < 544 < second  # one member leaves before the interruption at 544 frames, one after
    train(compose_config(*overrides, f"train.max_frames={interrupted_at}"), tmp_path / "resumed")
    resumed = train(compose_config(*overrides, "resume=true"), tmp_path / "resumed")
    assert [member["frames"] for member in resumed["members"]] == stopped_at
    for seed in (0, 1, 2):
        episodes = [
            (tmp_path / run / f"seed{seed}" / table_file("episodes")).read_text() for run in ("whole", "resumed")
        ]
        columns = [[line.split(",")[:5] for line in text.splitlines()] for text in episodes]
        assert columns[0] == columns[1]  # the same episodes, wall times aside
    checkpoints = [load_safely(tmp_path / run / CHECKPOINT) for run in ("whole", "resumed")]
    assert checkpoints[0]["in_batch"] == checkpoints[1]["in_batch"] == [0]
    torch.testing.assert_close(checkpoints[1]["agent"], checkpoints[0]["agent"], rtol=0, atol=0)
