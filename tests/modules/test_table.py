"""The transition table: exact after one try, optimistic where untried, what the planner makes of it, and the value of novelty solved on it."""

import pytest
import torch
from tensordict import TensorDict
from torchrl.data import Categorical, MultiOneHot, OneHot

from torchrl_mbe import (
    DynamicsLoss,
    NoveltyPlanner,
    RollingGaussianDensity,
    RollingWindowNovelty,
    TableActionValue,
    TableNoveltyValue,
    TransitionTable,
    VisitCounts,
)

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


def chain(length: int) -> tuple[TransitionTable, torch.Tensor]:
    """A table of a chain of ``length`` cells walked once by action 0 (cell i -> i + 1), and its cells."""
    cells = torch.eye(length)
    table = TransitionTable(length, Categorical(2))
    table.write(cells[:-1], torch.zeros(length - 1, dtype=torch.long), cells[1:])
    return table, cells


def test_value_iteration_carries_an_untried_pair_s_novelty_to_the_start_of_a_long_chain():
    cells = torch.eye(31)  # cells 0 .. 29 a chain under both actions; cell 29's pairs untried; cell 30 never seen
    table = TransitionTable(31, Categorical(2))
    for action in (0, 1):
        table.write(cells[:29], torch.full((29,), action), cells[1:30])
    counts = VisitCounts(31)
    counts.update(cells[:30].repeat(4, 1))  # a tried pair's successor scores 1 / sqrt(5); an untried pair's, 1
    value = TableNoveltyValue(table, counts, gamma=0.99)
    value.refresh()
    read = value(TensorDict({"observation": cells[[0, 28, 29]]}, [3]))["novelty_value"]
    torch.testing.assert_close(read, torch.tensor([[0.99**29] * 2, [0.99] * 2, [0.0] * 2]))


def test_a_successor_that_ended_an_episode_leads_nowhere():
    table, cells = chain(4)  # cell 3's actions are untried
    counts = VisitCounts(4)
    counts.update(cells)
    value = TableNoveltyValue(table, counts, gamma=0.5)
    value.refresh()
    assert value.values[2, 0] > 0  # towards cell 3's untried pairs
    table.write(cells[[2]], torch.tensor([0]), cells[[3]], torch.tensor([True]))  # arriving in cell 3 ends the episode
    value.refresh()
    assert value.values[2, 0] == 0 and value.values[0, 0] == 0.5 * 2**-0.5  # cell 0 sees only cell 2's bonus beyond


def test_the_counts_fast_cell_scores_are_the_scores_of_one_hot_states():
    counts = VisitCounts(4, batch_shape=[2])
    counts.update(torch.eye(4)[torch.tensor([[0, 1], [0, 2]])])
    torch.testing.assert_close(counts.cell_scores(), RollingWindowNovelty.cell_scores(counts))
    gaussian = RollingGaussianDensity(4, window=10)
    gaussian.update(torch.eye(4)[[0, 1, 2, 0, 1]])
    torch.testing.assert_close(gaussian.cell_scores(), gaussian.score(torch.eye(4)))


def test_a_reward_at_the_end_of_a_chain_is_valued_at_its_start_at_once_and_nothing_beyond_an_episode_end():
    cells = torch.eye(20)
    table = TransitionTable(20, Categorical(2))
    ends = torch.zeros(19, dtype=torch.bool)
    ends[-1] = True  # arriving in cell 19 ends the episode and pays 1
    rewards = torch.zeros(19)
    rewards[-1] = 1.0
    table.write(cells[:19], torch.ones(19, dtype=torch.long), cells[1:], ends, rewards)
    table.write(
        cells[[19]], torch.tensor([0]), cells[[0]], reward=torch.tensor([5.0])
    )  # a pair from the end: unreachable
    value = TableActionValue(table, gamma=0.9)
    value.refresh()
    torch.testing.assert_close(value.values[[0, 18], 1], torch.tensor([0.9**18, 1.0]))
    assert value.values[:19, 0].eq(0).all()  # action 0 untried: no value, neither optimistic nor pessimistic
