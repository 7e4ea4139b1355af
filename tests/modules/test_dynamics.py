from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torchrl.data import Categorical, LazyTensorStorage, MultiOneHot, OneHot, TensorDictReplayBuffer

from torchrl_mbe import DynamicsLoss, DynamicsModel

# A known linear system: s' = A s + B[a]
A = torch.tensor([[0.9, 0.1], [-0.2, 0.95]])
B = torch.tensor([[0.1, 0.0], [0.0, 0.0], [-0.1, 0.05]])


def linear_transitions(num: int, spec) -> TensorDict:
    observation = torch.rand(num, 2) * 2 - 1
    index = torch.randint(3, (num,))
    action = torch.nn.functional.one_hot(index, 3) if isinstance(spec, OneHot) else index
    next_observation = observation @ A.T + B[index]
    return TensorDict({"observation": observation, "action": action, ("next", "observation"): next_observation}, [num])


@pytest.mark.parametrize("spec", [OneHot(3), Categorical(3)], ids=["one-hot", "categorical"])
def test_dynamics_model_learns_a_linear_system_with_dynamics_loss(spec):
    dynamics = DynamicsModel(2, spec, num_cells=(64, 64))
    dynamics.fit_normalization(linear_transitions(1000, spec))
    loss = DynamicsLoss(dynamics)
    optimizer = torch.optim.Adam(loss.parameters(), lr=3e-3)
    test = linear_transitions(500, spec)
    untrained = loss(test)["mse_dynamics"].item()
    for _ in range(1500):
        optimizer.zero_grad()
        loss(linear_transitions(128, spec))["loss_dynamics"].backward()
        optimizer.step()
    trained = loss(test)["mse_dynamics"].item()
    assert trained < 1e-4 < untrained


def test_dynamics_model_predicts_deltas_added_to_the_observation():
    dynamics = DynamicsModel(2, OneHot(3))
    with torch.no_grad():
        for parameter in dynamics.net.parameters():
            parameter.zero_()
    td = TensorDict({"observation": torch.randn(4, 2), "action": OneHot(3).rand((4,))}, [4])
    # with a zero network the prediction is "no change"
    torch.testing.assert_close(dynamics(td)["predicted_observation"], td["observation"])


def test_paper_architecture_by_default():
    dynamics = DynamicsModel(2, OneHot(3))
    layers = [m for m in dynamics.net.modules() if isinstance(m, torch.nn.Linear)]
    assert [layer.out_features for layer in layers] == [24, 24, 2]
    assert sum(isinstance(m, torch.nn.ReLU) for m in dynamics.net.modules()) == 2


def test_normalization_refits_from_a_replay_buffer_and_travels_with_state_dict():
    buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(100))
    data = linear_transitions(100, OneHot(3))
    data["observation"] = data["observation"] * 5 + 3
    buffer.extend(data)
    dynamics = DynamicsModel(2, OneHot(3))
    dynamics.fit_normalization(buffer)
    torch.testing.assert_close(dynamics.observation_norm.loc, data["observation"].mean(0))
    torch.testing.assert_close(dynamics.observation_norm.scale, data["observation"].std(0))
    restored = DynamicsModel(2, OneHot(3))
    restored.load_state_dict(dynamics.state_dict())
    torch.testing.assert_close(
        restored(data.clone())["predicted_observation"], dynamics(data.clone())["predicted_observation"]
    )


def normalization(dynamics: DynamicsModel) -> list[torch.Tensor]:
    return [
        dynamics.observation_norm.loc,
        dynamics.observation_norm.scale,
        dynamics.delta_norm.loc,
        dynamics.delta_norm.scale,
    ]


def test_dynamics_loss_fits_a_fresh_model_on_the_first_batch_it_trains_on_and_the_flag_travels_with_state_dict():
    dynamics = DynamicsModel(2, OneHot(3))
    loss = DynamicsLoss(dynamics)
    first = linear_transitions(64, OneHot(3))
    first["observation"] = first["observation"] * 5 + 3
    with torch.no_grad():
        loss(first)  # a validation error, as the app measures on new frames: never fits
    assert not dynamics.normalization_fitted
    loss(first)["loss_dynamics"].backward()
    expected = DynamicsModel(2, OneHot(3))
    expected.fit_normalization(first)
    assert dynamics.normalization_fitted
    for fitted, reference in zip(normalization(dynamics), normalization(expected)):
        torch.testing.assert_close(fitted, reference)
    loss(linear_transitions(64, OneHot(3)))["loss_dynamics"].backward()  # later batches train, never refit
    for fitted, reference in zip(normalization(dynamics), normalization(expected)):
        torch.testing.assert_close(fitted, reference)
    restored = DynamicsModel(2, OneHot(3))
    restored.load_state_dict(dynamics.state_dict())
    assert restored.normalization_fitted
    older = {key: value for key, value in DynamicsModel(2, OneHot(3)).state_dict().items() if key != "_extra_state"}
    restored.load_state_dict(older)  # saved before the flag existed: its statistics are kept as they are
    assert restored.normalization_fitted


def test_an_explicit_fit_is_what_training_starts_from():
    buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(1000))
    buffer.extend(linear_transitions(1000, OneHot(3)))
    dynamics = DynamicsModel(2, OneHot(3))
    dynamics.fit_normalization(buffer)  # as the app does before its first update
    before = [statistic.clone() for statistic in normalization(dynamics)]
    DynamicsLoss(dynamics)(buffer.sample(16))["loss_dynamics"].backward()
    for statistic, fitted in zip(normalization(dynamics), before):
        assert torch.equal(statistic, fitted)


def test_a_dimension_that_never_moved_before_the_fit_does_not_blow_up_the_loss_when_it_does():
    early = linear_transitions(256, OneHot(3))
    early["observation"][:, 1] = 0.0  # a leg contact before the first touch: constant, and so is its delta
    early["next", "observation"][:, 1] = 0.0
    dynamics = DynamicsModel(2, OneHot(3))
    dynamics.fit_normalization(early)
    later = linear_transitions(256, OneHot(3))
    later["next", "observation"][:, 1] = (torch.rand(256) < 0.5).float()  # the contact now switches
    assert DynamicsLoss(dynamics)(later)["loss_dynamics"] < 10.0  # in units of the fitted spread, not of a 1e-6 floor


def test_dynamics_loss_reads_renamed_and_nested_keys():
    dynamics = DynamicsModel(2, OneHot(3))
    loss = DynamicsLoss(dynamics)
    data = linear_transitions(16, OneHot(3))
    renamed = TensorDict(
        {
            ("agent", "obs"): data["observation"],
            ("agent", "act"): data["action"],
            ("next", "agent", "obs"): data["next", "observation"],
        },
        [16],
    )
    loss.set_keys(observation=("agent", "obs"), action=("agent", "act"), next_observation=("next", "agent", "obs"))
    torch.testing.assert_close(loss(renamed)["loss_dynamics"], DynamicsLoss(dynamics)(data)["loss_dynamics"])
    assert ("agent", "obs") in loss.in_keys
    with pytest.raises(ValueError, match="not an accepted tensordict key"):
        loss.set_keys(obs="x")


def test_non_discrete_action_spec_is_rejected():
    from torchrl.data import Bounded

    with pytest.raises(TypeError, match="discrete action spec"):
        DynamicsModel(2, Bounded(-1, 1, (1,)))


def chain_transitions(num_cells: int, action: int) -> TensorDict:
    """One-hot cells of a chain, each stepping one cell right (wrapping) under ``action`` of 2."""
    cells = torch.eye(num_cells)
    return TensorDict(
        {"observation": cells, "action": torch.full((num_cells,), action), ("next", "observation"): cells.roll(1, 0)},
        [num_cells],
    )


def distance_to_nearest_cell(prediction: torch.Tensor) -> torch.Tensor:
    return torch.cdist(prediction, torch.eye(prediction.shape[-1])).min(-1).values


@pytest.mark.parametrize("num_members", [None, 3], ids=["single", "population"])
def test_a_randomized_prior_stays_frozen_and_out_of_the_optimizer(num_members):
    from torchrl_mbe.app.optim import adam

    dynamics = DynamicsModel(6, Categorical(2), (16,), num_members=num_members, prior_scale=1.0)
    optimizer = adam(dynamics.parameters(), 1e-2)
    trained = {id(parameter) for parameter in optimizer.param_groups[0]["params"]}
    assert trained == {id(parameter) for parameter in dynamics.net.parameters()}
    prior = [parameter.clone() for parameter in dynamics.prior.parameters()]
    data = chain_transitions(6, action=0)
    if num_members is not None:
        data = data.unsqueeze(1).expand(6, num_members).clone()
    loss = DynamicsLoss(dynamics)
    for _ in range(20):
        optimizer.zero_grad()
        loss(data)["loss_dynamics"].sum().backward()
        optimizer.step()
    for before, after in zip(prior, dynamics.prior.parameters()):
        torch.testing.assert_close(after, before)
    restored = DynamicsModel(6, Categorical(2), (16,), num_members=num_members, prior_scale=1.0)
    restored.load_state_dict(
        dynamics.state_dict()
    )  # the prior travels with a checkpoint (a resumed run predicts alike)
    with torch.no_grad():
        torch.testing.assert_close(
            restored(data.clone())["predicted_observation"], dynamics(data.clone())["predicted_observation"]
        )


@pytest.mark.parametrize(
    ("prior_num_cells", "scale"), [(None, 10.0), ((32,), 25.0)], ids=["as-wide-as-the-model", "narrow"]
)
def test_a_randomized_prior_sends_untried_actions_off_the_visited_states(prior_num_cells, scale):
    """Trained on action 0 only, the plain model predicts a visited cell for action 1; with a prior, wide or narrow, it does not."""
    distances = {}
    for prior_scale in (0.0, scale):
        torch.manual_seed(0)
        dynamics = DynamicsModel(6, Categorical(2), (64, 64), prior_scale=prior_scale, prior_num_cells=prior_num_cells)
        loss = DynamicsLoss(dynamics)
        optimizer = torch.optim.Adam(dynamics.net.parameters(), lr=3e-3)
        tried, untried = chain_transitions(6, action=0), chain_transitions(6, action=1)
        for _ in range(500):
            optimizer.zero_grad()
            loss(tried)["loss_dynamics"].backward()
            optimizer.step()
        with torch.no_grad():
            torch.testing.assert_close(
                dynamics(tried.clone())["predicted_observation"], tried["next", "observation"], atol=0.05, rtol=0
            )
            distances[prior_scale] = distance_to_nearest_cell(dynamics(untried.clone())["predicted_observation"])
    assert distances[0.0].max() < 0.7  # an untried action looks like a move to a known cell (cells are 1.41 apart)
    assert distances[scale].min() > 1.0  # with the prior, it lands where no visited state is


def test_a_negative_prior_scale_is_rejected():
    with pytest.raises(ValueError, match="prior_scale must be >= 0"):
        DynamicsModel(2, OneHot(3), prior_scale=-1.0)


@pytest.mark.parametrize("num_members", [None, 3], ids=["single", "population"])
def test_the_prior_has_its_own_hidden_layers_when_given(num_members):
    narrow = DynamicsModel(6, Categorical(2), (64,), num_members=num_members, prior_scale=1.0, prior_num_cells=(8, 4))
    sizes = [parameter.shape[-2] for name, parameter in narrow.prior.named_parameters() if name.endswith("weight")]
    assert sizes == [8, 4, 6]  # two hidden layers of its own, then the observation
    default = DynamicsModel(6, Categorical(2), (64,), num_members=num_members, prior_scale=1.0)
    assert [parameter.shape for parameter in default.prior.parameters()] == [
        parameter.shape for parameter in default.net.parameters()
    ]
    with pytest.raises(ValueError, match="prior_num_cells must be positive"):
        DynamicsModel(6, Categorical(2), (64,), prior_scale=1.0, prior_num_cells=(0,))


def test_raw_units_keep_identity_statistics_and_learn_one_hot_transitions():
    """normalize=False: nothing is fitted (not by the loss, not by fit_normalization), and errors are raw."""
    torch.manual_seed(0)
    dynamics = DynamicsModel(6, Categorical(2), (64,), normalize=False)
    loss = DynamicsLoss(dynamics)
    optimizer = torch.optim.Adam(dynamics.parameters(), lr=3e-3)
    data = chain_transitions(6, action=0)
    dynamics.fit_normalization(data)
    for _ in range(300):
        optimizer.zero_grad()
        losses = loss(data)
        losses["loss_dynamics"].backward()
        optimizer.step()
    for statistics in (dynamics.observation_norm, dynamics.delta_norm):
        torch.testing.assert_close(statistics.loc, torch.zeros(6))
        torch.testing.assert_close(statistics.scale, torch.ones(6))
    torch.testing.assert_close(losses["loss_dynamics"].detach(), losses["mse_dynamics"])
    with torch.no_grad():
        torch.testing.assert_close(
            dynamics(data.clone())["predicted_observation"], data["next", "observation"], atol=0.05, rtol=0
        )


def fit(dynamics: DynamicsModel, data: TensorDict, steps: int, lr: float) -> None:
    """``steps`` full-batch Adam steps of :class:`DynamicsLoss` on ``data`` (the prior, if any, stays frozen)."""
    loss = DynamicsLoss(dynamics)
    optimizer = torch.optim.Adam(dynamics.net.parameters(), lr=lr)
    for _ in range(steps):
        optimizer.zero_grad()
        loss(data)["loss_dynamics"].sum().backward()  # a population: each member's loss, its own gradient
        optimizer.step()


def grid_transitions(size: int, pairs: int, seed: int = 0) -> TensorDict:
    """``pairs`` distinct (cell, action) pairs of a DeepSea-like ``size`` x ``size`` one-hot grid, each to a random neighbour one row down."""
    generator = torch.Generator().manual_seed(seed)
    cells = torch.randperm((size - 1) * size, generator=generator)[:pairs]
    action = torch.randint(2, (pairs,), generator=generator)
    row, column = cells // size, cells % size
    next_cells = (row + 1) * size + (column + torch.randint(2, (pairs,), generator=generator) * 2 - 1).clamp(
        0, size - 1
    )
    cells_one_hot = torch.eye(size * size)
    return TensorDict(
        {"observation": cells_one_hot[cells], "action": action, ("next", "observation"): cells_one_hot[next_cells]},
        [pairs],
    )


def test_a_categorical_model_learns_more_next_cells_than_a_delta_model_of_its_width_can_span():
    """200 pairs of a 20 x 20 grid, 32 hidden units: the delta model's predictions span 33 directions and miss; a softmax's peak does not."""
    data = grid_transitions(20, 200)
    errors = {}
    for output in ("delta", "categorical"):
        torch.manual_seed(0)
        dynamics = DynamicsModel(400, Categorical(2), (32,), normalize=False, output=output)
        fit(dynamics, data, steps=600, lr=3e-3)
        with torch.no_grad():
            errors[output] = (dynamics(data.clone())["predicted_observation"] - data["next", "observation"]).norm(
                dim=-1
            )
    assert errors["delta"].median() > 1.0  # cells are 1.41 apart: 33 directions hold little of 200 targets
    assert errors["categorical"].max() < 0.1


@pytest.mark.parametrize("prior_scale", [0.0, 2.0], ids=["no-prior", "prior"])
@pytest.mark.parametrize("num_members", [None, 3], ids=["single", "population"])
def test_a_categorical_model_trains_on_the_cross_entropy_and_its_offset_cancelling_the_prior(num_members, prior_scale):
    torch.manual_seed(0)
    dynamics = DynamicsModel(
        9,
        Categorical(2),
        (16,),
        num_members=num_members,
        prior_scale=prior_scale,
        normalize=False,
        output="categorical",
    )
    batch = (4,) if num_members is None else (4, num_members)
    cells = torch.eye(9)[torch.randint(9, batch)]
    next_cells = torch.eye(9)[torch.randint(9, batch)]
    next_cells[0] = 0  # a terminal transition (DeepSea's next observation after its last row): the class of zeros
    data = TensorDict(
        {"observation": cells, "action": torch.randint(2, batch), ("next", "observation"): next_cells}, batch
    )
    logits, offset = dynamics.categorical_parts(cells, data["action"])
    probabilities = logits.softmax(-1)
    assert probabilities.shape[-1] == 10
    expected = -(next_cells * probabilities[..., :9].log()).sum(-1)
    expected[0] = -probabilities[0, ..., 9].log()
    probabilities = probabilities[..., :9]
    if prior_scale:
        expected = expected + offset.square().sum(-1)  # nothing to cancel it yet: an offset of the prior's size
        assert offset.norm(dim=-1).min() > 0.1
    else:
        assert offset is None
    prediction = dynamics(data.clone())["predicted_observation"]
    torch.testing.assert_close(prediction, probabilities if offset is None else probabilities + offset)
    losses = DynamicsLoss(dynamics)(data)
    torch.testing.assert_close(losses["loss_dynamics"], expected.mean(0))  # [M] in a population: one mean per member
    torch.testing.assert_close(losses["mse_dynamics"], (prediction - next_cells).square().mean(-1).mean(0).detach())


def test_a_categorical_model_predicts_zeros_after_the_last_row():
    """DeepSea's last row leads to an observation of zeros, which a softmax over the cells alone cannot predict."""
    data = chain_transitions(6, action=0)
    data["next", "observation"][-1] = 0
    torch.manual_seed(0)
    dynamics = DynamicsModel(
        6, Categorical(2), (16,), prior_scale=1.0, prior_num_cells=(4,), normalize=False, output="categorical"
    )
    fit(dynamics, data, steps=300, lr=1e-2)
    with torch.no_grad():
        torch.testing.assert_close(
            dynamics(data.clone())["predicted_observation"], data["next", "observation"], atol=0.05, rtol=0
        )


def test_a_categorical_model_with_a_prior_sends_untried_actions_off_the_visited_cells():
    """200 (cell, action) pairs of a 20 x 20 grid: a softmax alone puts each untried action on a visited cell; with the prior, none is near one."""
    tried = grid_transitions(20, 200)
    untried = tried.clone().set("action", 1 - tried["action"])
    visited = torch.cat([tried["observation"], tried["next", "observation"]]).unique(dim=0)
    distances = {}
    for prior_scale in (0.0, 25.0):
        torch.manual_seed(0)
        dynamics = DynamicsModel(
            400,
            Categorical(2),
            (64,),
            prior_scale=prior_scale,
            prior_num_cells=(8,),
            normalize=False,
            output="categorical",
        )
        fit(dynamics, tried, steps=600, lr=3e-3)
        with torch.no_grad():
            assert (dynamics(tried.clone())["predicted_observation"] - tried["next", "observation"]).norm(
                dim=-1
            ).max() < 0.1
            distances[prior_scale] = (
                torch.cdist(dynamics(untried.clone())["predicted_observation"], visited).min(-1).values
            )
    assert distances[0.0].max() < 0.1  # the tried action's next cell: an untried action looks familiar
    assert distances[25.0].min() > 1.0  # cells are 1.41 apart


def test_a_categorical_model_needs_raw_units_and_a_known_output():
    with pytest.raises(ValueError, match="output='categorical' .* pass normalize=False"):
        DynamicsModel(9, Categorical(2), output="categorical")
    with pytest.raises(ValueError, match=r"output must be one of \('delta', 'categorical'\), got 'softmax'"):
        DynamicsModel(9, Categorical(2), output="softmax", normalize=False)


@pytest.mark.parametrize("num_members", [None, 2], ids=["single", "population"])
def test_a_categorical_model_of_several_variables_predicts_each_one_with_its_own_softmax(num_members):
    """A position (5 values) that the action moves and a colour (3 values) that cycles, one-hot each (a MultiOneHot spec)."""
    position, colour, action = torch.meshgrid(torch.arange(5), torch.arange(3), torch.arange(2), indexing="ij")
    position, colour, action = position.flatten(), colour.flatten(), action.flatten()
    next_position, next_colour = (position + 2 * action - 1).clamp(0, 4), (colour + 1) % 3

    def observation(position, colour):
        observation = torch.cat([torch.eye(5)[position], torch.eye(3)[colour]], -1)
        return observation if num_members is None else observation.unsqueeze(-2).expand(-1, num_members, -1)

    member_action = action if num_members is None else action.unsqueeze(-1).expand(-1, num_members)
    data = TensorDict(
        {
            "observation": observation(position, colour),
            "action": member_action,
            ("next", "observation"): observation(next_position, next_colour),
        },
        member_action.shape,
    )
    torch.manual_seed(0)
    dynamics = DynamicsModel(
        MultiOneHot([5, 3]), Categorical(2), (32,), num_members=num_members, normalize=False, output="categorical"
    )
    fit(dynamics, data, steps=300, lr=1e-2)
    with torch.no_grad():
        prediction = dynamics(data.clone())["predicted_observation"]
    position_part, colour_part = prediction.split([5, 3], -1)
    for part in (position_part, colour_part):  # a distribution per variable (a group of zeros, never seen, keeps ~0)
        torch.testing.assert_close(part.sum(-1), torch.ones(member_action.shape), atol=1e-3, rtol=0)
    assert torch.equal(position_part.argmax(-1), data["next", "observation"][..., :5].argmax(-1))
    assert torch.equal(colour_part.argmax(-1), data["next", "observation"][..., 5:].argmax(-1))
    assert DynamicsLoss(dynamics)(data)["loss_dynamics"].max() < 0.1  # both cross-entropies, summed


@pytest.mark.parametrize("num_members", [None, 3])
@pytest.mark.parametrize("output", ["categorical", "delta"])
def test_a_model_reading_one_hot_cells_by_their_hot_index_predicts_and_learns_as_the_whole_product(num_members, output):
    spec, batch = OneHot(2), (16,) if num_members is None else (16, 3)
    options = {
        "output": output,
        "normalize": False,
        "prior_scale": 25.0,
        "prior_num_cells": [8],
        "num_members": num_members,
    }
    dense = DynamicsModel(36, spec, [32], **options)
    sparse = DynamicsModel(36, spec, [32], hot_entries=1, **options)
    sparse.load_state_dict(dense.state_dict())
    cells = torch.nn.functional.one_hot(torch.randint(36, batch), 36).float()
    action, target = spec.rand(batch), torch.randn(*batch, 36)
    for model in (dense, sparse):
        ((model.predict(cells, action) - target) ** 2).mean().backward()
    torch.testing.assert_close(sparse.predict(cells, action), dense.predict(cells, action))
    for dense_parameter, sparse_parameter in zip(dense.net.parameters(), sparse.net.parameters(), strict=True):
        torch.testing.assert_close(sparse_parameter.grad, dense_parameter.grad)
    spread = torch.softmax(torch.randn(*batch, 36), -1)  # a prediction rolled on (horizon > 1): the whole product
    torch.testing.assert_close(sparse.predict(spread, action), dense.predict(spread, action))
    compiled = torch.compile(sparse.predict, fullgraph=True, backend="aot_eager")  # as a compiled policy calls it
    torch.testing.assert_close(compiled(cells, action), dense.predict(cells, action))
    if num_members is None:  # the columns of cells not in the batch are never read
        unread = min(set(range(36)) - set(cells.argmax(-1).tolist()))
        with torch.no_grad():
            sparse.net[0].weight[:, unread] = float("nan")
        assert sparse.predict(cells, action).isfinite().all()
    with pytest.raises(ValueError, match="hot_entries reads raw one-hot codes"):
        DynamicsModel(36, spec, hot_entries=1)
