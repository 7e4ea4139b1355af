"""Bootstrapped DQN with priors: heads never mix, one head acts per episode, K = 1 without prior is DQNLoss."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import torch
from tensordict import TensorDict
from torch import nn
from torchrl.data import Composite, OneHot
from torchrl.envs import GymEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import MLP, QValueActor
from torchrl.objectives import DQNLoss

from torchrl_mbe import make_env
from torchrl_mbe.app.optim import GradientStep
from torchrl_mbe.envs.transforms import BootstrapHeads
from torchrl_mbe.modules.bootstrap import BootstrappedQValueActor, EnsembleQNetwork
from torchrl_mbe.modules.normalization import Standardize
from torchrl_mbe.objectives.bootstrap import BootstrapDQNLoss

SPEC = OneHot(3)
OBSERVATION_SIZE = 2
LOSS_OPTIONS = {"delay_value": True, "double_dqn": True, "loss_function": "smooth_l1", "action_space": SPEC}


def ensemble(num_heads: int, prior_scale: float = 5.0, seed: int = 0) -> BootstrappedQValueActor:
    torch.manual_seed(seed)
    return BootstrappedQValueActor(EnsembleQNetwork(OBSERVATION_SIZE, 3, [16], num_heads, prior_scale), SPEC)


def transitions(batch_size: int, num_heads: int, mask_prob: float = 0.5, seed: int = 1) -> TensorDict:
    generator = torch.Generator().manual_seed(seed)
    flags = torch.rand(batch_size, 1, generator=generator) < 0.1
    return TensorDict(
        observation=torch.randn(batch_size, OBSERVATION_SIZE, generator=generator),
        action=SPEC.rand((batch_size,)),
        next=TensorDict(
            observation=torch.randn(batch_size, OBSERVATION_SIZE, generator=generator),
            reward=torch.randn(batch_size, 1, generator=generator),
            done=flags,
            terminated=flags,
            bootstrap_mask=torch.rand(batch_size, num_heads, generator=generator) < mask_prob,
        ),
        batch_size=[batch_size],
    )


def head_gradients(actor: BootstrappedQValueActor, batch: TensorDict) -> dict:
    loss = BootstrapDQNLoss(actor, **LOSS_OPTIONS)
    loss.make_value_estimator(gamma=0.99)
    loss(batch)["loss"].backward()
    params = actor.network.trainable.params
    return {key: value.grad.clone() for key, value in params.items(include_nested=True, leaves_only=True)}


def test_changing_one_heads_mask_and_parameters_leaves_every_other_heads_gradient_unchanged():
    batch = transitions(64, 4)
    before = head_gradients(ensemble(4), batch.clone())
    changed_actor, changed_batch = ensemble(4), batch.clone()
    changed_batch["next", "bootstrap_mask"][:, 2] = ~changed_batch["next", "bootstrap_mask"][:, 2]
    with torch.no_grad():
        for value in changed_actor.network.trainable.params.values(include_nested=True, leaves_only=True):
            value[2].add_(1.0)
    after = head_gradients(changed_actor, changed_batch)
    for key in before:
        for head in (0, 1, 3):
            torch.testing.assert_close(after[key][head], before[key][head], rtol=0, atol=0)
        assert not torch.equal(after[key][2], before[key][2])


def test_a_head_learns_nothing_from_a_transition_its_mask_leaves_out():
    batch = transitions(32, 2, mask_prob=1.0)
    batch["next", "bootstrap_mask"][:, 1] = False
    gradients = head_gradients(ensemble(2), batch)
    assert all(bool(gradient[1].eq(0).all()) and bool(gradient[0].ne(0).any()) for gradient in gradients.values())


def test_the_priors_never_learn():
    actor = ensemble(3)
    loss = BootstrapDQNLoss(actor, **LOSS_OPTIONS)
    loss.make_value_estimator(gamma=0.99)
    loss(transitions(16, 3))["loss"].backward()
    prior = actor.network.prior.params.values(include_nested=True, leaves_only=True)
    assert all(value.grad is None and not value.requires_grad for value in prior)


def test_one_head_without_prior_or_mask_takes_the_steps_dqn_loss_takes():
    actor = ensemble(1, prior_scale=0.0)
    single = MLP(in_features=OBSERVATION_SIZE, out_features=3, num_cells=[16], activation_class=nn.ReLU)
    with torch.no_grad():
        for key, value in actor.network.trainable.params.items(include_nested=True, leaves_only=True):
            single.get_parameter(".".join(key)).copy_(value[0])
    losses = [
        BootstrapDQNLoss(actor, **LOSS_OPTIONS),
        DQNLoss(QValueActor(single, spec=SPEC, in_keys=["observation"]), **LOSS_OPTIONS),
    ]
    optimizers = [torch.optim.Adam(loss.parameters(), lr=1e-2) for loss in losses]
    for step in range(3):
        batch = transitions(32, 1, mask_prob=1.0, seed=step)
        for loss, optimizer in zip(losses, optimizers):
            loss.make_value_estimator(gamma=0.99)
            optimizer.zero_grad()
            loss(batch.clone())["loss"].backward()
            optimizer.step()
    for key, value in actor.network.trainable.params.items(include_nested=True, leaves_only=True):
        torch.testing.assert_close(value[0], single.get_parameter(".".join(key)), rtol=1e-5, atol=1e-6)


def test_each_env_acts_with_one_head_per_episode_drawn_again_at_its_reset():
    env = make_env("mountaincar", num_envs=4, seed=0, max_episode_steps=5)  # episodes of 5 steps
    env.append_transform(BootstrapHeads(num_heads=50, mask_prob=0.5))
    torch.manual_seed(0)
    rollout = env.rollout(15, break_when_any_done=False)  # three episodes per env
    heads = rollout["head"].reshape(4, 3, 5)
    assert bool((heads == heads[..., :1]).all())  # constant within an episode
    assert bool((heads[:, 1:, 0] != heads[:, :-1, 0]).any())  # drawn again at each reset
    assert 0.4 < rollout["next", "bootstrap_mask"].float().mean() < 0.6


def test_the_actor_acts_with_its_head_while_exploring_and_with_the_heads_mean_when_greedy():
    actor = ensemble(4)
    observation = torch.randn(5, OBSERVATION_SIZE)
    heads = actor.network(observation.unsqueeze(-2).expand(5, 4, OBSERVATION_SIZE))
    head = torch.tensor([0, 1, 2, 3, 1])
    with set_exploration_type(ExplorationType.RANDOM):
        exploring = actor(TensorDict(observation=observation, head=head, batch_size=[5]))
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        greedy = actor(TensorDict(observation=observation, head=head, batch_size=[5]))
    torch.testing.assert_close(exploring["action_value"], heads[torch.arange(5), head])
    torch.testing.assert_close(greedy["action_value"], heads.mean(-2))
    assert torch.equal(greedy["action"].argmax(-1), heads.mean(-2).argmax(-1))


def population_of_ensembles(num_members: int, num_heads: int) -> BootstrappedQValueActor:
    torch.manual_seed(0)
    norm = Standardize((num_members, OBSERVATION_SIZE))
    norm.fit(torch.randn(100, num_members, OBSERVATION_SIZE) * torch.arange(1.0, num_members + 1).unsqueeze(-1))
    network = EnsembleQNetwork(OBSERVATION_SIZE, 3, [16], num_heads, 5.0, input_norm=norm, num_members=num_members)
    return BootstrappedQValueActor(network, SPEC)


def member_as_single_ensemble(population: BootstrappedQValueActor, member: int) -> BootstrappedQValueActor:
    network = EnsembleQNetwork(OBSERVATION_SIZE, 3, [16], population.network.num_heads, 5.0, input_norm=Standardize(2))
    single = BootstrappedQValueActor(network, SPEC)
    single.load_state_dict(population.member_state_dict(member))  # strict: exactly one ensemble's keys
    return single


def test_a_population_members_ensemble_acts_and_learns_as_the_single_ensemble_its_weights_make():
    population = population_of_ensembles(num_members=3, num_heads=4)
    single = member_as_single_ensemble(population, member=1)
    members_batch = torch.stack([transitions(32, 4, seed=seed) for seed in range(3)], dim=1)  # [32, M]
    head = torch.randint(4, (32, 3))
    with set_exploration_type(ExplorationType.RANDOM):
        acting = population(members_batch.select("observation").set("head", head))
        alone = single(members_batch[:, 1].select("observation").set("head", head[:, 1]))
    torch.testing.assert_close(acting["action_value"][:, 1], alone["action_value"])
    population_losses = [BootstrapDQNLoss(population, **LOSS_OPTIONS), BootstrapDQNLoss(single, **LOSS_OPTIONS)]
    for loss in population_losses:
        loss.make_value_estimator(gamma=0.99)
    member_loss = population_losses[0](members_batch.clone())["member_loss"]
    single_loss = population_losses[1](members_batch[:, 1].clone())["member_loss"]
    assert member_loss.shape == (12,)  # M * K heads
    torch.testing.assert_close(member_loss[4:8], single_loss)
    member_loss.sum().backward()
    single_loss.sum().backward()
    for key, value in single.network.trainable.params.items(include_nested=True, leaves_only=True):
        torch.testing.assert_close(population.network.trainable.params[key].grad[4:8], value.grad)


def test_a_population_member_acts_with_its_own_heads_and_is_greedy_by_their_mean():
    population = population_of_ensembles(num_members=2, num_heads=3)
    observation = torch.randn(5, 2, OBSERVATION_SIZE)
    heads = population.network(observation.unsqueeze(-2).expand(5, 2, 3, OBSERVATION_SIZE))  # [5, M, K, A]
    head = torch.randint(3, (5, 2))
    with set_exploration_type(ExplorationType.RANDOM):
        exploring = population(TensorDict(observation=observation, head=head, batch_size=[5, 2]))
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        greedy = population(TensorDict(observation=observation, head=head, batch_size=[5, 2]))
    chosen = heads.gather(-2, head[..., None, None].expand(5, 2, 1, 3)).squeeze(-2)
    torch.testing.assert_close(exploring["action_value"], chosen)
    torch.testing.assert_close(greedy["action_value"], heads.mean(-2))


@pytest.mark.parametrize("num_heads, mask_prob", [(0, 0.5), (3, 1.5), (3, -0.1)])
def test_no_heads_or_a_mask_probability_outside_zero_to_one_is_refused(num_heads, mask_prob):
    with pytest.raises(ValueError, match=r"num_heads must be positive and mask_prob in \[0, 1\]"):
        BootstrapHeads(num_heads=num_heads, mask_prob=mask_prob)


def test_the_actor_takes_a_composite_spec_and_declares_its_outputs_as_a_q_value_actor_does():
    actor = BootstrappedQValueActor(EnsembleQNetwork(2, 3, [16], 4, 5.0), Composite(action=SPEC))
    out = actor(TensorDict(observation=torch.randn(6, 2), head=torch.zeros(6, dtype=torch.long), batch_size=[6]))
    assert out["action"].shape == (6, 3) and bool((out["action"].sum(-1) == 1).all())  # one-hot actions
    assert set(actor.spec.keys()) == set(QValueActor(MLP(out_features=3), spec=SPEC).spec.keys())


@pytest.mark.parametrize("hot_entries", [None, 1])
def test_the_actor_compiles_with_fullgraph_and_acts_as_the_eager_one(hot_entries):
    torch.manual_seed(0)
    actor = BootstrappedQValueActor(EnsembleQNetwork(25, 3, [16], 4, 5.0, hot_entries=hot_entries), SPEC)
    compiled = torch.compile(actor, fullgraph=True, backend="aot_eager")
    cells = nn.functional.one_hot(torch.randint(25, (6,)), 25).float()
    td = TensorDict(observation=cells, head=torch.arange(6) % 4, batch_size=[6])
    with set_exploration_type(ExplorationType.RANDOM):
        assert torch.equal(compiled(td.clone())["action"], actor(td.clone())["action"])


def usage_pipeline() -> str:
    """The Python block of docs/usage.md's Bootstrapped DQN section."""
    usage = (Path(__file__).resolve().parents[2] / "docs" / "usage.md").read_text()
    section = usage.split("### Bootstrapped DQN with randomized priors, in a plain TorchRL loop\n", 1)[1]
    (block,) = re.findall(r"```python\n(.*?)```", section.split("\n### ", 1)[0], flags=re.DOTALL)
    return block


def test_the_documented_pipeline_runs_as_written_and_its_greedy_ensemble_balances_longer_than_at_the_start():
    namespace = {"__name__": "__usage__"}
    exec(compile(usage_pipeline(), "docs/usage.md", "exec"), namespace)
    actor, buffer = namespace["actor"], namespace["buffer"]
    heads = buffer[:]["head"]
    assert len(torch.unique(heads)) == 10  # every head acted in some episode
    env = GymEnv("CartPole-v1")
    env.set_seed(1)
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        greedy_steps = env.rollout(500, actor).numel()  # no "head": the heads' mean acts
    episode_lengths = buffer[:]["next", "step_count"][buffer[:]["next", "done"]]
    assert greedy_steps > 2 * episode_lengths[:10].float().mean()  # 107 against 25 as written


@pytest.mark.parametrize(("num_members", "reported"), [(1, 0.5), (3, [0.5, 2.5, 4.5])])
def test_an_ensembles_step_reports_each_members_mean_loss_over_its_heads_and_clips_each_head(num_members, reported):
    weights = nn.Parameter(torch.ones(2 * num_members))
    head_losses = lambda scale: weights * scale  # [M * K] losses, head h's gradient scale[h]
    step = GradientStep(
        head_losses, torch.optim.SGD([weights], lr=1.0), 1.0, num_members=2 * num_members, heads_per_member=2
    )
    assert step(torch.arange(2.0 * num_members)) == reported
    moved = 1.0 - weights.detach()
    torch.testing.assert_close(moved, torch.arange(2.0 * num_members).clamp(max=1.0))  # each head's norm clipped to 1


@pytest.mark.parametrize("num_members", [None, 2])
def test_an_ensemble_on_one_hot_codes_computes_from_the_hot_entries_what_the_product_computes(num_members):
    groups = (30, 7)  # two categorical variables: every code has two ones
    members = () if num_members is None else (num_members,)
    networks = []
    for hot_entries in (None, 2):
        torch.manual_seed(0)
        network = EnsembleQNetwork(37, 3, [16, 16], 4, 5.0, num_members=num_members, hot_entries=hot_entries)
        networks.append(BootstrappedQValueActor(network, SPEC))
    generator = torch.Generator().manual_seed(1)
    codes = lambda: torch.cat(
        [nn.functional.one_hot(torch.randint(size, (64, *members), generator=generator), size) for size in groups], -1
    ).float()
    batch = TensorDict(
        observation=codes(),
        action=SPEC.rand((64, *members)),
        next=TensorDict(
            observation=codes(),
            reward=torch.randn(64, *members, 1, generator=generator),
            done=torch.zeros(64, *members, 1, dtype=torch.bool),
            terminated=torch.zeros(64, *members, 1, dtype=torch.bool),
            bootstrap_mask=torch.ones(64, *members, 4, dtype=torch.bool),
        ),
        batch_size=[64, *members],
    )
    gradients = []
    for actor in networks:
        loss = BootstrapDQNLoss(actor, **LOSS_OPTIONS)
        loss.make_value_estimator(gamma=0.99)
        loss(batch.clone())["loss"].backward()
        gradients.append([value.grad for value in actor.network.trainable.params.values(True, True)])
    for dense, sparse in zip(*gradients):
        torch.testing.assert_close(sparse, dense)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        values = [actor(batch.select("observation"))["action_value"] for actor in networks]
    torch.testing.assert_close(values[1], values[0])


def test_an_ensemble_refuses_to_standardize_the_one_hot_codes_it_reads_by_their_hot_entries():
    with pytest.raises(ValueError, match="hot_entries reads raw one-hot codes: pass no input_norm"):
        EnsembleQNetwork(9, 3, [16], 4, 5.0, input_norm=Standardize(9), hot_entries=1)
