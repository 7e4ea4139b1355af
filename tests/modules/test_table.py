"""The transition table: exact after one try, optimistic where untried, and what the planner makes of it."""

import pytest
import torch
from tensordict import TensorDict
from torchrl.data import Categorical, MultiOneHot, OneHot

from torchrl_mbe import DynamicsLoss, NoveltyPlanner, TransitionTable, VisitCounts

CELLS = torch.eye(5)


def test_a_tried_pair_predicts_its_successor_and_an_untried_one_the_states_never_seen():
    table = TransitionTable(5, Categorical(2))
    table.write(CELLS[[0, 1]], torch.tensor([1, 1]), CELLS[[1, 2]])  # 0 -> 1 -> 2 by action 1
    prediction = table.predict(CELLS[[0, 1, 0]], torch.tensor([1, 1, 0]))
    torch.testing.assert_close(prediction[0], CELLS[1])
    torch.testing.assert_close(prediction[1], CELLS[2])
    torch.testing.assert_close(prediction[2], torch.tensor([0, 0, 0, 0.5, 0.5]))  # cells 3 and 4 were never seen


def test_a_new_try_replaces_the_successor_and_an_episode_end_predicts_zeros():
    table = TransitionTable(OneHot(5), OneHot(2))
    action = torch.tensor([[True, False]])
    table.write(CELLS[[3]], action, CELLS[[4]])
    table.write(CELLS[[3]], action, torch.zeros(1, 5))  # the same pair now ends the episode
    torch.testing.assert_close(table.predict(CELLS[[3]], action), torch.zeros(1, 5))
    torch.testing.assert_close(table.predict(torch.zeros(1, 5), action), torch.zeros(1, 5))  # from the end: nothing


def test_once_every_state_is_seen_an_untried_pair_predicts_their_mean():
    table = TransitionTable(5, Categorical(2))
    table.write(CELLS, torch.zeros(5, dtype=torch.long), CELLS.roll(1, 0))
    torch.testing.assert_close(table.predict(CELLS[[0]], torch.tensor([1])), torch.full((1, 5), 0.2))


def test_the_counts_planner_tries_the_untried_action_and_the_table_is_a_dynamics_module():
    table = TransitionTable(5, Categorical(2))
    table.write(CELLS[[0]], torch.tensor([0]), CELLS[[1]])
    counts = VisitCounts(5)
    counts.update(CELLS[[0, 1]])
    planner = NoveltyPlanner(table, counts, Categorical(2))
    assert planner.plan(CELLS[[0]])[0].item() == 1  # action 0 leads to cell 1, visited; action 1 is untried
    batch = TensorDict(
        {"observation": CELLS[[0]], "action": torch.tensor([0]), ("next", "observation"): CELLS[[1]]}, [1]
    )
    assert DynamicsLoss(table)(batch)["mse_dynamics"].item() == 0.0


def test_it_refuses_states_of_several_groups_and_predictions_as_inputs():
    with pytest.raises(ValueError, match="one group"):
        TransitionTable(MultiOneHot([3, 2]), Categorical(2))
    with pytest.raises(ValueError, match="one-hot states or zeros"):
        TransitionTable(5, Categorical(2)).predict(torch.full((1, 5), 0.2), torch.tensor([0]))
