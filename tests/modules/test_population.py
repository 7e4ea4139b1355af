"""Populations: members are independent, a member's update is a single network's, the buffer samples per member."""

from __future__ import annotations

import copy
import io

import pytest
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import OneHot
from torchrl.envs.transforms import RNDTransform
from torchrl.envs.transforms.rnd import RunningMeanStd
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import MLP, MultiAgentMLP, QValueActor
from torchrl.objectives import DQNLoss, HardUpdate, RNDLoss

from torchrl_mbe.app.optim import clip_grad_norm_per_member_
from torchrl_mbe.app.replay import PopulationReplayBuffer
from torchrl_mbe.envs.transforms import PopulationRNDTransform
from torchrl_mbe.modules.networks import (
    MembersMLP,
    make_members_mlp,
    make_per_action_mlp,
    make_population_q_actor,
    member_state_dict,
    reset_members_noise,
)
from torchrl_mbe.objectives.population import PopulationDQNLoss, PopulationRNDLoss

SPEC = OneHot(3)
OBSERVATION_SIZE = 2
NUM_CELLS = [16, 16]
MAX_GRAD_NORM = 0.05  # small enough that every member is clipped
CHANGED = 2  # the member whose data or parameters one copy changes


class Learner:
    """A loss with its fused Adam and hard target update: the whole update of a population or of one network."""

    def __init__(self, loss: DQNLoss, clip) -> None:
        self.loss = loss
        self.clip = clip
        self.optimizer = torch.optim.Adam(loss.parameters(), lr=1e-2, fused=True)
        self.target_updater = HardUpdate(loss, value_network_update_interval=1)

    def update(self, batch: TensorDictBase) -> TensorDict:
        """One update; returns the loss's output with the gradient norm before clipping (``"grad_norm"``)."""
        self.optimizer.zero_grad(set_to_none=True)
        out = self.loss(batch)
        out["loss"].backward()
        out["grad_norm"] = self.clip(list(self.loss.parameters()))
        self.optimizer.step()
        self.target_updater.step()
        return out


def population_learner(num_members: int) -> Learner:
    actor = make_population_q_actor(OBSERVATION_SIZE, SPEC, NUM_CELLS, num_members)
    loss = PopulationDQNLoss(actor, delay_value=True, double_dqn=True, loss_function="smooth_l1", action_space=SPEC)
    loss.make_value_estimator(gamma=0.99)
    return Learner(loss, lambda parameters: clip_grad_norm_per_member_(parameters, MAX_GRAD_NORM, num_members))


def single_learner(parameters: TensorDictBase) -> Learner:
    """A single Q-network of the same architecture holding ``parameters`` (one member's slice)."""
    network = make_per_action_mlp(OBSERVATION_SIZE, SPEC, NUM_CELLS)
    network.load_state_dict(parameters.flatten_keys(".").to_dict())
    actor = QValueActor(network, spec=SPEC, in_keys=["observation"])
    loss = DQNLoss(actor, delay_value=True, double_dqn=True, loss_function="smooth_l1", action_space=SPEC)
    loss.make_value_estimator(gamma=0.99)
    return Learner(loss, lambda parameters: torch.nn.utils.clip_grad_norm_(parameters, MAX_GRAD_NORM))


def member_parameters(learner: Learner) -> TensorDictBase:
    """The population's online parameters, stacked ``[M, ...]`` (MultiAgentMLP's ``params``)."""
    return learner.loss.value_network_params["module", "0", "module", "params"]


def target_parameters(learner: Learner) -> TensorDictBase:
    return learner.loss.target_value_network_params["module", "0", "module", "params"]


def transitions(num_rows: int, num_members: int) -> TensorDict:
    flags = torch.rand(num_rows, num_members, 1) < 0.1
    return TensorDict(
        observation=torch.randn(num_rows, num_members, OBSERVATION_SIZE),
        action=SPEC.rand((num_rows, num_members)),
        next=TensorDict(
            observation=torch.randn(num_rows, num_members, OBSERVATION_SIZE),
            reward=torch.randn(num_rows, num_members, 1),
            done=flags,
            terminated=flags,
            batch_size=[num_rows, num_members],
        ),
        batch_size=[num_rows, num_members],
    )


def assert_members_equal(left: TensorDictBase, right: TensorDictBase, members, equal: bool) -> None:
    for key, value in left.items(include_nested=True, leaves_only=True):
        for member in members:
            assert torch.equal(value[member], right[key][member]) is equal, (key, member)


def run_updates(learner: Learner, batches: list[TensorDict]) -> None:
    for batch in batches:
        learner.update(batch.clone())


def test_changing_one_members_data_leaves_every_other_members_update_unchanged():
    learner = population_learner(4)
    twin = Learner(copy.deepcopy(learner.loss), learner.clip)
    batches = [transitions(32, 4) for _ in range(3)]
    changed = [batch.clone() for batch in batches]
    for batch in changed:
        batch["observation"][:, CHANGED] += 1.0
        batch["next", "reward"][:, CHANGED] *= 100.0  # a gradient far above the clip
    run_updates(learner, batches)
    run_updates(twin, changed)
    others = [0, 1, 3]
    assert_members_equal(member_parameters(learner), member_parameters(twin), others, equal=True)
    assert_members_equal(target_parameters(learner), target_parameters(twin), others, equal=True)
    assert_members_equal(member_parameters(learner), member_parameters(twin), [CHANGED], equal=False)


def test_changing_one_members_parameters_leaves_every_other_members_update_unchanged():
    learner = population_learner(4)
    twin = Learner(copy.deepcopy(learner.loss), learner.clip)
    with torch.no_grad():
        for parameters in (member_parameters(twin), target_parameters(twin)):
            for value in parameters.values(include_nested=True, leaves_only=True):
                value[CHANGED] *= 3.0
    batches = [transitions(32, 4) for _ in range(3)]
    run_updates(learner, batches)
    run_updates(twin, batches)
    assert_members_equal(member_parameters(learner), member_parameters(twin), [0, 1, 3], equal=True)
    assert_members_equal(target_parameters(learner), target_parameters(twin), [0, 1, 3], equal=True)


def test_a_members_update_is_the_update_of_its_own_single_network():
    population = population_learner(3)
    singles = [single_learner(member_parameters(population)[member].detach().clone()) for member in range(3)]
    batches = [transitions(32, 3) for _ in range(2)]
    for batch in batches:
        population_out = population.update(batch.clone())
        for member, single in enumerate(singles):
            single_out = single.update(batch[:, member].clone())
            torch.testing.assert_close(population_out["member_loss"][member], single_out["loss"].detach())
            torch.testing.assert_close(
                population_out["grad_norm"][member], single_out["grad_norm"], rtol=1e-4, atol=1e-7
            )
    for member, single in enumerate(singles):
        expected = single.loss.value_network_params["module", "0", "module"]
        for key, value in member_parameters(population).items(include_nested=True, leaves_only=True):
            torch.testing.assert_close(value.grad[member], expected[key].grad, rtol=1e-4, atol=1e-6)
            torch.testing.assert_close(value[member], expected[key], rtol=1e-4, atol=1e-6)


def test_a_population_of_one_starts_from_the_single_networks_weights():
    torch.manual_seed(3)
    population = make_population_q_actor(OBSERVATION_SIZE, SPEC, NUM_CELLS, 1)
    torch.manual_seed(3)
    single = make_per_action_mlp(OBSERVATION_SIZE, SPEC, NUM_CELLS)
    stacked = population.module[0].params.flatten_keys(".")
    for name, value in single.state_dict().items():
        assert torch.equal(stacked[name][0], value), name


def twin_networks(num_members: int, noise_std: float | None = None) -> tuple[MembersMLP, MultiAgentMLP]:
    """A ``MembersMLP`` and TorchRL's ``MultiAgentMLP`` holding the same parameters (and noise)."""
    network = make_members_mlp(OBSERVATION_SIZE, 3, NUM_CELLS, num_members, noise_std=noise_std)
    reset_members_noise(network)
    vmapped = make_members_mlp(OBSERVATION_SIZE, 3, NUM_CELLS, num_members, noise_std=noise_std, batched=False)
    vmapped.load_state_dict(network.state_dict())
    return network, vmapped


@pytest.mark.parametrize("num_members", [1, 3])
@pytest.mark.parametrize("batch_shape", [(), (5,), (4, 6)])
@pytest.mark.parametrize(
    "noise_std, mode",
    [(None, ExplorationType.RANDOM), (0.5, ExplorationType.RANDOM), (0.5, ExplorationType.DETERMINISTIC)],
)
def test_the_members_batched_products_compute_multiagentmlps_values_and_gradients_to_the_bit(
    num_members, batch_shape, noise_std, mode
):
    network, vmapped = twin_networks(num_members, noise_std)
    states = torch.randn(*batch_shape, num_members, OBSERVATION_SIZE)
    with set_exploration_type(mode):
        values, vmapped_values = network(states), vmapped(states)
    assert network.batched_products and torch.equal(values, vmapped_values)
    values.square().sum().backward()
    vmapped_values.square().sum().backward()
    # without noise (DETERMINISTIC) the noise scales get no gradient: None on both sides
    for (name, parameter), twin in zip(network.named_parameters(), vmapped.parameters(), strict=True):
        torch.testing.assert_close(parameter.grad, twin.grad, rtol=0, atol=0, msg=name)


@pytest.mark.parametrize("noise_std", [None, 0.5])
def test_the_dqn_loss_reads_the_target_parameters_it_swaps_into_the_members_network(noise_std):
    network, vmapped = twin_networks(3, noise_std)
    losses = [
        PopulationDQNLoss(QValueActor(twin, spec=SPEC, in_keys=["observation"]), delay_value=True, action_space=SPEC)
        for twin in (network, vmapped)
    ]
    batch = transitions(32, 3)
    for loss in losses:
        loss.make_value_estimator(gamma=0.99)
        loss.target_value_network_params.apply_(lambda target: target.add_(0.5))  # the target is not the online network
    with set_exploration_type(ExplorationType.RANDOM):
        outputs = [loss(batch.clone()) for loss in losses]
    assert torch.equal(outputs[0]["member_loss"], outputs[1]["member_loss"])
    outputs[0]["loss"].backward()
    outputs[1]["loss"].backward()
    for online, twin in zip(losses[0].parameters(), losses[1].parameters(), strict=True):
        torch.testing.assert_close(online.grad, twin.grad, rtol=0, atol=0)


def test_a_network_sharing_its_parameters_takes_multiagentmlps_call():
    network = MembersMLP(
        n_agent_inputs=OBSERVATION_SIZE, n_agent_outputs=3, n_agents=3, centralized=False, share_params=True
    )
    vmapped = MultiAgentMLP(
        n_agent_inputs=OBSERVATION_SIZE, n_agent_outputs=3, n_agents=3, centralized=False, share_params=True
    )
    vmapped.load_state_dict(network.state_dict())
    states = torch.randn(5, 3, OBSERVATION_SIZE)
    assert not network.batched_products and torch.equal(network(states), vmapped(states))
    with pytest.raises(ValueError, match="forward_from needs a MembersMLP that computes with batched products"):
        network.forward_from(states, 0)


def test_noisy_members_act_on_their_noise_only_while_exploring():
    network = make_members_mlp(OBSERVATION_SIZE, 3, NUM_CELLS, 2, noise_std=0.5)
    states = torch.randn(5, 2, OBSERVATION_SIZE)
    with set_exploration_type(ExplorationType.RANDOM):
        noisy = network(states)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        assert not torch.equal(network(states), noisy)


def test_each_member_is_glorot_initialized_on_its_own_slice():
    weight = make_population_q_actor(OBSERVATION_SIZE, SPEC, [64], 8).module[0].params["0", "weight"]  # [8, 64, 2]
    bound = (6 / (OBSERVATION_SIZE + 64)) ** 0.5  # a member's fan-in and fan-out, not the stack's
    assert weight.abs().max() <= bound
    assert weight.abs().amax(dim=(1, 2)).min() > 0.8 * bound
    assert not torch.equal(weight[0], weight[1])


def noisy_values(
    actor: QValueActor, states: torch.Tensor, mode: ExplorationType = ExplorationType.RANDOM
) -> torch.Tensor:
    """The action values of ``states`` (``[B, M, F]``): with the actor's current noise sample, or its noise-free mean (``DETERMINISTIC``)."""
    with set_exploration_type(mode):
        return actor(TensorDict(observation=states, batch_size=states.shape[:-1]))["action_value"]


def test_a_noisy_populations_reset_draws_new_noise_for_every_member_on_its_own():
    actor = make_population_q_actor(OBSERVATION_SIZE, SPEC, NUM_CELLS, 4, noise_std=0.5)
    states = torch.randn(8, 1, OBSERVATION_SIZE).expand(8, 4, OBSERVATION_SIZE)  # the same states for every member
    before = noisy_values(actor, states)
    actor.apply(reset_members_noise)
    after = noisy_values(actor, states)
    assert (before != after).any(0).all()  # every member's values moved
    noise = actor.module[0].params["0", "weight_epsilon"]  # [M, hidden, features]
    assert all(not torch.equal(noise[0], noise[member]) for member in (1, 2, 3))  # no member shares another's draw
    mean = noisy_values(actor, states, ExplorationType.DETERMINISTIC)
    actor.apply(reset_members_noise)
    assert torch.equal(
        noisy_values(actor, states, ExplorationType.DETERMINISTIC), mean
    )  # the noise-free mean is untouched


def test_a_noisy_members_state_loads_into_a_single_noisy_network_that_acts_as_the_member():
    actor = make_population_q_actor(OBSERVATION_SIZE, SPEC, NUM_CELLS, 3, noise_std=0.5)
    actor.apply(reset_members_noise)
    single = QValueActor(
        make_per_action_mlp(OBSERVATION_SIZE, SPEC, NUM_CELLS, noise_std=0.5), spec=SPEC, in_keys=["observation"]
    )
    single.load_state_dict(member_state_dict(actor.state_dict(), 1))  # strict: exactly a single NoisyNet's keys
    states = torch.randn(8, 3, OBSERVATION_SIZE)
    torch.testing.assert_close(noisy_values(single, states[:, 1]), noisy_values(actor, states)[:, 1])


def test_the_noisy_loss_sees_each_reset():
    actor = make_population_q_actor(OBSERVATION_SIZE, SPEC, NUM_CELLS, 2, noise_std=0.5)
    loss = PopulationDQNLoss(actor, delay_value=True, action_space=SPEC)
    loss.deterministic_sampling_mode = ExplorationType.RANDOM  # as exploration=noisy learns: through its noise
    loss.make_value_estimator(gamma=0.99)
    batch = transitions(8, 2)
    before = loss(batch.clone())["member_loss"]
    actor.apply(reset_members_noise)
    after = loss(batch.clone())["member_loss"]
    assert (before != after).all()


def gradients(num_members: int) -> list[torch.Tensor]:
    parameters = [torch.zeros(num_members, 5, 3, requires_grad=True), torch.zeros(num_members, 5, requires_grad=True)]
    for parameter in parameters:
        parameter.grad = torch.randn_like(parameter)
    return parameters


def _rnd_networks(num_members: int = 3) -> tuple[torch.nn.Module, torch.nn.Module]:
    """An RND target and predictor of ``num_members`` members (tanh, torch's default initialization: RNDExplorer's)."""
    return tuple(
        make_members_mlp(OBSERVATION_SIZE, 8, [16], num_members, activation_class=torch.nn.Tanh, glorot=False)
        for _ in range(2)
    )


def _member_mlp(network: torch.nn.Module, member: int) -> MLP:
    single = MLP(in_features=OBSERVATION_SIZE, out_features=8, num_cells=[16], activation_class=torch.nn.Tanh)
    single.load_state_dict(member_state_dict(network.state_dict(), member))
    return single


def _members_observations(steps: int, num_envs: int, num_members: int) -> torch.Tensor:
    """``[steps, num_envs, M, F]`` observations whose mean and spread differ from member to member."""
    scale = torch.arange(1.0, num_members + 1).view(1, 1, num_members, 1)
    return torch.randn(steps, num_envs, num_members, OBSERVATION_SIZE) * scale + 3 * scale


def test_an_rnd_members_rewards_and_statistics_are_a_single_rnd_transforms_on_its_own_observations():
    torch.manual_seed(0)
    target, predictor = _rnd_networks()
    population = PopulationRNDTransform(target, predictor)
    singles = [RNDTransform(_member_mlp(target, member), _member_mlp(predictor, member)) for member in range(3)]
    for observation in _members_observations(steps=6, num_envs=4, num_members=3):
        rewards = population._step(TensorDict(), TensorDict(observation=observation, batch_size=[4, 3]))[
            "intrinsic_reward"
        ]
        for member, single in enumerate(singles):
            alone = single._step(TensorDict(), TensorDict(observation=observation[:, member], batch_size=[4]))[
                "intrinsic_reward"
            ]
            torch.testing.assert_close(rewards[:, member], alone)
    for member, single in enumerate(singles):
        torch.testing.assert_close(population.obs_rms.mean[member], single.obs_rms.mean)
        torch.testing.assert_close(population.reward_rms.var[member, 0], single.reward_rms.var)


def _rnd_batch(observation: torch.Tensor) -> TensorDict:
    return TensorDict(
        next=TensorDict(observation=observation, batch_size=observation.shape[:2]), batch_size=observation.shape[:2]
    )


def test_an_rnd_members_predictor_gradient_is_its_single_rnd_loss_gradient():
    torch.manual_seed(0)
    target, predictor = _rnd_networks()
    observation = _members_observations(steps=1, num_envs=64, num_members=3)[0]  # [B, M, F]
    statistics = RunningMeanStd(shape=(3, OBSERVATION_SIZE))
    statistics.update(observation)
    PopulationRNDLoss(predictor, target, obs_rms=statistics, update_fraction=1.0)(_rnd_batch(observation))[
        "loss_predictor"
    ].backward()
    for member in range(3):
        single_predictor = _member_mlp(predictor, member)
        single_statistics = RunningMeanStd(shape=(OBSERVATION_SIZE,))
        single_statistics.update(observation[:, member])
        single = RNDLoss(single_predictor, _member_mlp(target, member), obs_rms=single_statistics, update_fraction=1.0)
        single(TensorDict(next=TensorDict(observation=observation[:, member], batch_size=[64]), batch_size=[64]))[
            "loss_predictor"
        ].backward()
        torch.testing.assert_close(predictor.params["0", "weight"].grad[member], single_predictor[0].weight.grad)


def test_each_rnd_member_averages_over_its_own_kept_samples():
    torch.manual_seed(0)
    target, predictor = _rnd_networks()
    observation = _members_observations(steps=1, num_envs=64, num_members=3)[0]
    changed = observation.clone()
    changed[:, CHANGED] += 1.0
    loss = PopulationRNDLoss(predictor, target, update_fraction=0.25)
    member_losses = []
    for batch in (observation, changed):
        torch.manual_seed(1)  # the same kept samples in both
        member_losses.append(loss(_rnd_batch(batch))["member_loss"])
    per_sample = (predictor(observation) - target(observation)).pow(2).mean(-1)  # [B, M]
    torch.manual_seed(1)
    kept = torch.rand(per_sample.shape) < 0.25
    torch.testing.assert_close(
        member_losses[0], (per_sample * kept).sum(0) / kept.sum(0)
    )  # not diluted by the other members' samples
    torch.testing.assert_close(member_losses[0][:CHANGED], member_losses[1][:CHANGED])
    assert not torch.equal(member_losses[0][CHANGED], member_losses[1][CHANGED])


def test_a_huge_gradient_in_one_member_does_not_shrink_the_others():
    plain, huge = gradients(4), gradients(4)
    for left, right in zip(plain, huge):
        right.grad.copy_(left.grad)
        right.grad[CHANGED] *= 1e6
    clip_grad_norm_per_member_(plain, 1.0, 4)
    norms = clip_grad_norm_per_member_(huge, 1.0, 4)
    for left, right in zip(plain, huge):
        for member in (0, 1, 3):
            assert torch.equal(left.grad[member], right.grad[member])
    assert norms[CHANGED] > 1e5
    clipped = torch.stack([parameter.grad[CHANGED].norm() for parameter in huge]).norm()
    torch.testing.assert_close(clipped, torch.tensor(1.0))


def test_clipping_a_population_of_one_is_torchs_clipping():
    population, single = gradients(1), gradients(1)
    for left, right in zip(population, single):
        right.grad.copy_(left.grad)
    norms = clip_grad_norm_per_member_(population, 0.5, 1)
    norm = torch.nn.utils.clip_grad_norm_(single, 0.5)
    torch.testing.assert_close(norms, norm.view(1))
    for left, right in zip(population, single):
        torch.testing.assert_close(left.grad, right.grad)


def test_clipping_refuses_a_parameter_without_a_member_dimension():
    shared = torch.zeros(5, requires_grad=True)
    with pytest.raises(ValueError, match="stacked over 4 members"):
        clip_grad_norm_per_member_([*gradients(4), shared], 1.0, 4)


def numbered(num_rows: int, num_members: int, start: int = 0) -> TensorDict:
    """Row r of member m holds ``100 * (start + r) + m``: a sample says where it came from."""
    rows = torch.arange(start, start + num_rows).view(-1, 1) * 100 + torch.arange(num_members)
    done = (rows // 100 % 2 == 0).unsqueeze(-1)  # alternate rows
    return TensorDict(x=rows.float().unsqueeze(-1), next=TensorDict(done=done), batch_size=[num_rows, num_members])


def test_the_buffer_is_a_ring():
    buffer = PopulationReplayBuffer(capacity=4, num_members=2)
    assert buffer.extend(numbered(3, 2)).tolist() == [0, 1, 2]
    assert len(buffer) == 3
    assert buffer.extend(numbered(3, 2, start=3)).tolist() == [3, 0, 1]
    assert len(buffer) == 4
    assert buffer.state_dict()["storage"]["x"][:, 1, 0].tolist() == [401.0, 501.0, 201.0, 301.0]
    assert buffer.extend(numbered(6, 2, start=6)).tolist() == [0, 1, 2, 3]  # the last 4 rows of 6, where they fall
    assert buffer.state_dict()["storage"]["x"][:, 0, 0].tolist() == [800.0, 900.0, 1000.0, 1100.0]


def test_each_member_samples_its_own_rows_with_its_own_indices():
    buffer = PopulationReplayBuffer(capacity=50, num_members=3)
    buffer.extend(numbered(50, 3))
    torch.manual_seed(1)
    sample = buffer.sample(64)
    index = sample["index"]
    assert sample.batch_size == (64, 3)
    assert not torch.equal(index[:, 0], index[:, 1]) and not torch.equal(index[:, 1], index[:, 2])
    torch.testing.assert_close(sample["x"].squeeze(-1), (index * 100 + torch.arange(3)).float())
    assert torch.equal(sample["next", "done"].squeeze(-1), index % 2 == 0)


def test_a_members_sample_depends_on_its_own_storage_only():
    data = numbered(20, 4)
    changed = data.clone()
    changed["x"][:, CHANGED] = -1.0
    samples = []
    for stored in (data, changed):
        buffer = PopulationReplayBuffer(capacity=20, num_members=4)
        buffer.extend(stored)
        torch.manual_seed(5)
        samples.append(buffer.sample(32))
    others = [0, 1, 3]
    assert torch.equal(samples[0][:, others]["x"], samples[1][:, others]["x"])
    assert (samples[1]["x"][:, CHANGED] == -1.0).all()


def test_the_buffer_state_round_trips_through_torch_load_weights_only():
    buffer = PopulationReplayBuffer(capacity=8, num_members=3)
    buffer.extend(numbered(11, 3))
    file = io.BytesIO()
    torch.save(buffer.state_dict(), file)
    file.seek(0)
    restored = PopulationReplayBuffer(capacity=8, num_members=3)
    restored.load_state_dict(torch.load(file, weights_only=True))
    assert len(restored) == len(buffer)
    for copy_ in (buffer, restored):
        copy_.extend(numbered(2, 3, start=50))
    torch.manual_seed(2)
    expected = buffer.sample(16)
    torch.manual_seed(2)
    assert (restored.sample(16) == expected).all()


def test_the_buffer_refuses_a_batch_without_the_member_dimension():
    with pytest.raises(ValueError, match=r"\[\*N, 3\]"):
        PopulationReplayBuffer(capacity=8, num_members=3).extend(numbered(4, 2))
