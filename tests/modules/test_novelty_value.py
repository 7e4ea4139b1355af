"""The value of novelty: its TD target, and what it teaches the exploring step on a chain whose only new state is far away."""

import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.data import OneHot
from torchrl.modules import MLP
from torchrl.objectives import HardUpdate

from torchrl_mbe import ModelBasedExplorationPolicy, NoveltyPlanner, NoveltyValueLoss, VisitCounts

CELLS = 6  # a chain 0 .. 5; action 0 steps left (or stays at 0), action 1 steps right
ACTIONS = OneHot(2)


class ChainDynamics(nn.Module):
    """The chain's exact next cell, as a dynamics module the planner calls."""

    def forward(self, observation: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        cell = observation.argmax(-1) + torch.where(action[..., 1], 1, -1)
        return nn.functional.one_hot(cell.clamp(0, CELLS - 1), CELLS).to(observation.dtype)


def value_network() -> TensorDictModule:
    return TensorDictModule(MLP(in_features=CELLS, out_features=2, num_cells=[32]), ["observation"], ["novelty_value"])


def chain_planner() -> NoveltyPlanner:
    dynamics = TensorDictModule(ChainDynamics(), ["observation", "action"], ["next_observation"])
    counts = VisitCounts(CELLS, batch_shape=[1])
    counts.update(torch.eye(CELLS)[torch.arange(5).repeat(20)].unsqueeze(1))  # cells 0-4 visited 20 times; 5 never
    return NoveltyPlanner(dynamics, counts, ACTIONS)


def walked_transitions() -> TensorDict:
    """Both actions from cells 0 .. 3, and only the left one from cell 4: the step to cell 5 was never taken."""
    cells = torch.tensor([0, 0, 1, 1, 2, 2, 3, 3, 4])
    actions = torch.tensor([0, 1, 0, 1, 0, 1, 0, 1, 0])
    successors = (cells + torch.where(actions == 1, 1, -1)).clamp(0, CELLS - 1)
    return TensorDict(
        {
            "observation": torch.eye(CELLS)[cells],
            "action": torch.eye(2, dtype=torch.bool)[actions],
            "successor_observation": torch.eye(CELLS)[successors],
            "successor_terminated": torch.zeros(len(cells), 1, dtype=torch.bool),
        },
        [len(cells)],
    )


def test_the_target_is_the_discounted_novelty_of_the_rarest_state_reachable_and_stops_at_the_end_of_an_episode():
    torch.manual_seed(0)
    novelty = torch.tensor([[0.2, 0.9]]).expand(4, 2)  # every successor: its actions' predicted novelty
    loss = NoveltyValueLoss(value_network(), lambda states: novelty, ACTIONS, gamma=0.5)
    batch = walked_transitions()[:4]
    batch["successor_terminated"][0] = True
    beyond = loss.values(batch["successor_observation"], loss.target_value_network_params)
    expected = 0.5 * torch.maximum(novelty, beyond).amax(-1) * torch.tensor([0.0, 1.0, 1.0, 1.0])
    torch.testing.assert_close(loss(batch)["target_novelty_value"], expected.mean())


def test_a_state_never_seen_four_steps_away_turns_the_first_exploring_step_towards_it():
    torch.manual_seed(0)
    planner = chain_planner()
    network = value_network()
    loss = NoveltyValueLoss(network, planner.replayed_action_scores, ACTIONS, gamma=0.9)
    updater = HardUpdate(loss, value_network_update_interval=20)
    optimizer = torch.optim.Adam(loss.parameters(), lr=1e-2)
    batch = walked_transitions()
    for _ in range(600):
        optimizer.zero_grad()
        loss(batch)["loss_novelty_value"].backward()
        optimizer.step()
        updater.step()
    start = torch.eye(CELLS)[:1]
    one_step = planner.action_scores(start)[0]
    assert one_step[0] == one_step[1]  # the paper's planner: both next states equally familiar
    left = TensorDictModule(lambda obs: torch.eye(2, dtype=torch.bool)[[0] * obs.shape[0]], ["observation"], ["action"])
    deep = ModelBasedExplorationPolicy(
        left, planner, eps_init=1.0, eps_end=1.0, annealing_num_steps=1, novelty_value=network
    )
    step = deep(TensorDict({"observation": start}, [1]))
    assert step["action"][0].tolist() == [False, True]  # right: towards cell 5, 0.9 ** 4 of a new state's novelty away
    values = network(TensorDict({"observation": start}, [1]))["novelty_value"][0]
    torch.testing.assert_close(values[1], torch.tensor(0.9**4), atol=0.05, rtol=0)
