from __future__ import annotations

import copy

import pytest
import torch
from dynamics_doubles import ShiftDynamics
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torchrl.collectors import Collector
from torchrl.envs import ExplorationType, GymEnv, SerialEnv, set_exploration_type
from torchrl.modules import MLP, QValueActor

from torchrl_mbe import DynamicsModel, ModelBasedExplorationPolicy, NoveltyPlanner, RollingGaussianDensity, make_env
from torchrl_mbe.modules.exploration import check_eps_schedule

SHIFTS = torch.tensor([[-0.1, 0.0], [0.0, 0.0], [0.5, 0.5]])


def build_policy(env, *, window=50, batch_shape=(), dynamics=None, **kwargs):
    spec = env.action_spec
    actor = QValueActor(MLP(out_features=3, num_cells=[48]), spec=spec, in_keys=["observation"])
    density = RollingGaussianDensity(2, window=window, batch_shape=batch_shape)
    planner = NoveltyPlanner(dynamics or DynamicsModel(2, spec), density, spec)
    kwargs = {"eps_init": 1.0, "eps_end": 0.01, "annealing_num_steps": 100, **kwargs}
    return ModelBasedExplorationPolicy(actor, planner, **kwargs)


@pytest.fixture
def env():
    return make_env("mountaincar", seed=0)


def test_deterministic_mode_is_exactly_the_greedy_actor_and_leaves_the_window_alone(env):
    policy = build_policy(env)
    td = env.reset()
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        for _ in range(20):
            assert torch.equal(policy(td.clone())["action"], policy.actor(td.clone())["action"])
        env.rollout(30, policy)
    assert policy.novelty.num_stored == 0


def test_random_mode_with_eps_one_takes_the_planners_action():
    env = make_env("mountaincar", seed=0)
    policy = build_policy(env, dynamics=ShiftDynamics(SHIFTS))
    policy.novelty.update(0.01 * torch.randn(50, 2) + torch.tensor([-0.5, 0.0]))
    # greedy would say "push left" on every state; planning says action 2 (furthest shift)
    torch.nn.init.zeros_(policy.actor.module[0].module[-1].weight)
    with torch.no_grad():
        policy.actor.module[0].module[-1].bias.copy_(torch.tensor([1.0, 0.0, 0.0]))
    td = TensorDict({"observation": torch.tensor([-0.5, 0.0])}, [])
    with set_exploration_type(ExplorationType.RANDOM):
        actions = torch.stack([policy(td.clone())["action"] for _ in range(10)])
    assert (actions.argmax(-1) == 2).all()
    policy.eps.fill_(0.0)
    assert policy(td.clone())["action"].argmax() == 0


def test_window_holds_the_last_visited_states_after_a_collector_run(env):
    policy = build_policy(env, window=50)
    collector = Collector(env, policy, frames_per_batch=40, total_frames=120)
    observations = torch.cat([batch["observation"] for batch in collector])
    collector.shutdown()
    torch.testing.assert_close(policy.novelty.window_states(), observations[-50:])


def test_window_is_per_environment_in_a_batched_collector():
    env = SerialEnv(3, lambda: make_env("mountaincar"))
    env.set_seed(0)
    policy = build_policy(env, window=10, batch_shape=(3,))
    collector = Collector(env, policy, frames_per_batch=30, total_frames=60)
    batches = [batch for batch in collector]  # each batch is (3 envs, 10 steps)
    collector.shutdown()
    observations = torch.cat([batch["observation"] for batch in batches], 1)
    torch.testing.assert_close(policy.novelty.window_states(), observations[:, -10:])


def test_rollout_explores_and_eps_anneals_linearly_or_exponentially(env):
    policy = build_policy(env, annealing_num_steps=100)
    rollout = env.rollout(25, policy)
    assert policy.novelty.num_stored == 25 == rollout.shape[0]
    policy.step(50)
    assert policy.eps.item() == pytest.approx(0.505)
    policy.step(1000)
    assert policy.eps.item() == pytest.approx(0.01)
    paper = build_policy(env, schedule="exponential", annealing_num_steps=9209)
    paper.step(1)
    assert paper.eps.item() == pytest.approx(0.9995, abs=1e-6)  # the paper's per-step decay
    paper.step(9208)
    assert paper.eps.item() == pytest.approx(0.01, abs=1e-6)


def test_state_dict_round_trip_keeps_eps_window_and_weights(env):
    policy = build_policy(env)
    env.rollout(30, policy)
    policy.step(40)
    restored = build_policy(env)
    restored.load_state_dict(policy.state_dict())
    assert restored.eps.item() == policy.eps.item()
    torch.testing.assert_close(restored.novelty.window_states(), policy.novelty.window_states())
    td = env.reset()
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        assert torch.equal(restored(td.clone())["action"], policy(td.clone())["action"])


def test_warm_up_takes_random_actions_until_the_model_is_trusted(env):
    policy = build_policy(env, dynamics=ShiftDynamics(SHIFTS), model_error_threshold=0.1)
    policy.novelty.update(0.01 * torch.randn(50, 2))
    td = TensorDict({"observation": torch.zeros(2)}, [])
    untrusted = torch.stack([policy(td.clone())["action"].long().argmax() for _ in range(300)])
    assert set(untrusted.tolist()) == {0, 1, 2}
    assert not policy.report_model_error(0.5)
    assert policy.report_model_error(0.05)
    trusted = torch.stack([policy(td.clone())["action"].long().argmax() for _ in range(20)])
    assert (trusted == 2).all()


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"eps_init": 0.1, "eps_end": 0.5}, "eps_end <= eps_init"),
        ({"annealing_num_steps": 0}, "annealing_num_steps"),
        ({"schedule": "cosine"}, "schedule must be"),
        ({"schedule": "exponential", "eps_end": 0.0}, "eps_end > 0"),
    ],
)
def test_bad_schedules_are_rejected_with_one_line(env, kwargs, message):
    with pytest.raises(ValueError, match=message):
        build_policy(env, **kwargs)
    schedule = {"eps_init": 1.0, "eps_end": 0.01, "annealing_num_steps": 100, "schedule": "linear", **kwargs}
    with pytest.raises(ValueError, match=message) as error:
        check_eps_schedule(**schedule)
    assert "\n" not in str(error.value)


def test_a_collector_feeds_the_window_only_the_states_it_visits():
    env = make_env("mountaincar", num_envs=4, seed=0)
    spec = env.action_spec_unbatched
    actor = QValueActor(MLP(out_features=3, num_cells=[8]), spec=spec, in_keys=["observation"])
    planner = NoveltyPlanner(DynamicsModel(2, spec), RollingGaussianDensity(2, window=50, batch_shape=(4,)), spec)
    policy = ModelBasedExplorationPolicy(actor, planner)
    collector = Collector(env, policy, frames_per_batch=8, total_frames=-1)
    assert int(planner.novelty.num_seen) == 0  # building the collector visits nothing
    batch = next(iter(collector))
    assert int(planner.novelty.num_seen) == batch.shape[-1] == 2
    assert torch.equal(planner.novelty.window_states(), batch["observation"])
    collector.shutdown()


def test_the_components_take_the_composite_spec_egreedy_takes_and_read_the_sizes_from_the_specs():
    env = GymEnv("MountainCar-v0")
    actor = QValueActor(MLP(out_features=3, num_cells=[8]), spec=env.action_spec, in_keys=["observation"])
    dynamics = DynamicsModel(env.observation_spec, actor.spec)  # Composite(observation=...), Composite(action=...)
    planner = NoveltyPlanner(dynamics, RollingGaussianDensity(window=50), actor.spec)
    policy = ModelBasedExplorationPolicy(actor, planner)
    rollout = env.rollout(10, policy)
    assert dynamics.observation_size == 2 and planner.num_actions == 3
    assert torch.equal(
        rollout["action"].sum(-1), torch.ones(10, dtype=rollout["action"].dtype)
    )  # one-hot, as the env's
    assert planner.novelty.num_stored == 10
    with pytest.raises(ValueError, match="entry 'observation'.*env.observation_spec") as error:
        DynamicsModel(actor.spec, actor.spec)
    assert "\n" not in str(error.value)
    with pytest.raises(ValueError, match="entry 'action'"):
        NoveltyPlanner(dynamics, RollingGaussianDensity(window=50), env.observation_spec)


def step_both(policies, td):
    """Each policy acts on ``td`` from the same random state; their actions."""
    state = torch.get_rng_state()
    actions = []
    for policy in policies:
        torch.set_rng_state(state)
        actions.append(policy(td.clone())["action"])
    return actions


def test_the_policy_compiles_with_fullgraph_and_acts_as_the_eager_one():
    # torch.compile(policy, fullgraph=True) is what a Collector's compile_policy does (backend aside: the default,
    # inductor, takes a minute here; test_a_collector_runs_the_policy_compiled covers it).
    env = make_env("mountaincar", num_envs=4, seed=0)
    eager = build_policy(env, window=8, batch_shape=(4,), eps_init=0.5, eps_end=0.5, model_error_threshold=0.1)
    twin = copy.deepcopy(eager)
    compiled = torch.compile(twin, fullgraph=True, backend="aot_eager")
    td = env.reset()
    for step in range(16):  # the window fills (8 states), then wraps
        if step == 4:
            assert eager.report_model_error(0.0) and twin.report_model_error(0.0)
        eager_action, compiled_action = step_both([eager, compiled], td)
        if step >= 4:  # both plan: same draws, same actions (before, each draws its random actions its own way)
            assert torch.equal(compiled_action, eager_action)
        _, td = env.step_and_maybe_reset(td.set("action", eager_action))
    assert int(twin.novelty.num_seen) == int(eager.novelty.num_seen) == 16
    assert torch.equal(twin.novelty.states, eager.novelty.states)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        assert torch.equal(compiled(td.clone())["action"], eager.actor(td.clone())["action"])
    assert int(twin.novelty.num_seen) == 16  # evaluation leaves the window alone


@pytest.mark.slow
def test_a_collector_runs_the_policy_compiled():
    env = make_env("mountaincar", num_envs=4, seed=0)
    policy = build_policy(env, window=50, batch_shape=(4,))
    collector = Collector(env, policy, frames_per_batch=32, total_frames=96, compile_policy={"fullgraph": True})
    batches = [batch for batch in collector]
    collector.update_policy_weights_()
    collector.shutdown()
    observations = torch.cat([batch["observation"] for batch in batches], 1)
    # The compiled wrapper hides the policy's spec, so the Collector probes the policy once on the first observation
    torch.testing.assert_close(policy.novelty.window_states(), torch.cat([observations[:, :1], observations], 1))


def test_value_weight_makes_an_exploring_step_weigh_the_q_values_against_the_novelty():
    env = make_env("mountaincar", seed=0)
    td = TensorDict({"observation": torch.tensor([-0.5, 0.0])}, [])
    prefers_action_0 = TensorDictModule(
        lambda obs: torch.tensor([1.0, 0.0, 0.0]).expand(*obs.shape[:-1], 3), ["observation"], ["v"]
    )
    chosen = {}
    for value_weight, action_value in ((0.0, None), (1e6, None), (1e6, prefers_action_0)):
        policy = build_policy(env, dynamics=ShiftDynamics(SHIFTS), value_weight=value_weight, action_value=action_value)
        policy.novelty.update(0.01 * torch.randn(50, 2) + torch.tensor([-0.5, 0.0]))
        torch.nn.init.zeros_(policy.actor.module[0].module[-1].weight)
        with torch.no_grad():  # Q prefers action 1, the planner's novelty action 2
            policy.actor.module[0].module[-1].bias.copy_(torch.tensor([0.0, 1.0, 0.0]))
        with set_exploration_type(ExplorationType.RANDOM):
            chosen[value_weight, action_value is None] = {int(policy(td.clone())["action"].argmax()) for _ in range(5)}
    assert chosen == {(0.0, True): {2}, (1e6, True): {1}, (1e6, False): {0}}  # the values given replace the actor's


def test_a_novelty_reward_scores_each_next_state_against_the_states_the_policy_visited_before_it():
    from torchrl_mbe import VisitCounts
    from torchrl_mbe.envs.transforms import NoveltyReward

    env = make_env("deepsea", size=5, seed=0)
    spec = env.action_spec_unbatched
    counts = VisitCounts(25, batch_shape=env.batch_size)
    actor = QValueActor(MLP(out_features=2, num_cells=[8]), spec=spec, in_keys=["observation"])
    policy = ModelBasedExplorationPolicy(actor, NoveltyPlanner(DynamicsModel(25, spec), counts, spec), eps_init=1.0)
    env.append_transform(NoveltyReward(counts))
    batch = next(iter(Collector(env, policy, frames_per_batch=40, total_frames=-1)))
    visited = batch["observation"].reshape(40, 25).argmax(-1).tolist()
    next_cells = batch["next", "observation"].reshape(40, 25)
    expected = [
        (visited[: step + 1].count(int(next_cells[step].argmax())) + 1) ** -0.5 if next_cells[step].any() else 0.0
        for step in range(40)
    ]  # a terminal step's next observation is all zeros: no cell, no bonus
    torch.testing.assert_close(batch["next", "intrinsic_reward"].reshape(40), torch.tensor(expected))
    assert counts.counts.sum() == 40  # only the policy writes the counts: each visited state once
