from __future__ import annotations

import pytest
import torch
from dynamics_doubles import ShiftDynamics
from tensordict import TensorDict
from torchrl.data import Categorical, OneHot

from torchrl_mbe import GaussianKernelNovelty, NoveltyPlanner, RollingGaussianDensity
from torchrl_mbe.modules.planner import random_argmax

SHIFTS = torch.tensor([[-0.1, 0.0], [0.0, 0.0], [0.5, 0.5]])  # action 2 leaves the window furthest


def fitted(novelty_cls, batch_shape=()):
    novelty = novelty_cls(2, window=50, batch_shape=batch_shape)
    novelty.update(0.05 * torch.randn(50, *batch_shape, 2))
    return novelty


@pytest.mark.parametrize("novelty_cls", [RollingGaussianDensity, GaussianKernelNovelty])
@pytest.mark.parametrize("batch_size", [(), (4,), (2, 3)], ids=["unbatched", "batch", "2d-batch"])
def test_planner_picks_the_rarest_predicted_state_for_any_batch_shape(novelty_cls, batch_size):
    planner = NoveltyPlanner(ShiftDynamics(SHIFTS), fitted(novelty_cls), OneHot(3))
    td = planner(TensorDict({"observation": torch.zeros(*batch_size, 2)}, batch_size))
    assert td["action"].shape == (*batch_size, 3)
    assert (td["action"].long().argmax(-1) == 2).all()
    assert td["novelty_scores"].shape == (*batch_size, 3)
    predictions = torch.zeros(*batch_size, 2).unsqueeze(-2) + SHIFTS
    torch.testing.assert_close(td["novelty_scores"], planner.novelty.score(predictions.movedim(-2, 0)).movedim(0, -1))


def test_planner_argmin_density_equals_argmax_score_per_environment_window():
    # Env 0's window sits where action 2 leads, env 1's where action 0 leads.
    novelty = RollingGaussianDensity(2, window=50, batch_shape=(2,))
    around = torch.stack([SHIFTS[2], SHIFTS[0]])
    novelty.update(around + 0.01 * torch.randn(50, 2, 2))
    planner = NoveltyPlanner(ShiftDynamics(SHIFTS, one_hot=False), novelty, Categorical(3))
    td = planner(TensorDict({"observation": torch.zeros(2, 2)}, [2]))
    log_density = -td["novelty_scores"]
    assert torch.equal(td["action"], log_density.argmin(-1))
    assert td["action"].dtype == Categorical(3).dtype
    assert td["action"][0] != 2 and td["action"][1] != 0


def test_random_argmax_breaks_ties_uniformly():
    picks = random_argmax(torch.zeros(3000, 3))
    counts = torch.bincount(picks, minlength=3).float()
    assert (counts > 800).all()
    assert torch.equal(random_argmax(torch.tensor([[0.0, 2.0, 1.0]])), torch.tensor([1]))


def test_two_step_planning_finds_a_rare_state_a_greedy_step_misses():
    # Action 0 moves a little right; action 1 moves left and, from the left,
    # action 1 again moves far down: one step prefers 0, two steps prefer 1.
    class TrapDynamics(ShiftDynamics):
        def forward(self, tensordict):
            obs, index = tensordict["observation"], tensordict["action"].long().argmax(-1)
            right = obs + torch.tensor([0.3, 0.0])
            left = obs + torch.tensor([-0.1, 0.0])
            far = obs + torch.tensor([0.0, -3.0])
            went_left = (obs[..., 0] < -0.05).unsqueeze(-1)
            second = torch.where(went_left, far, left)
            tensordict["predicted_observation"] = torch.where((index == 0).unsqueeze(-1), right, second)
            return tensordict

    novelty = RollingGaussianDensity(2, window=50)
    novelty.update(0.05 * torch.randn(50, 2))
    td = TensorDict({"observation": torch.zeros(2)}, [])
    one_step = NoveltyPlanner(TrapDynamics(SHIFTS), novelty, OneHot(2))(td.clone())
    two_step = NoveltyPlanner(TrapDynamics(SHIFTS), novelty, OneHot(2), horizon=2)(td.clone())
    assert one_step["action"].long().argmax() == 0
    assert two_step["action"].long().argmax() == 1


class FirstActionDynamics(ShiftDynamics):
    """From the origin, action ``a`` moves by ``shifts[a]``; afterwards every action drifts outwards."""

    def forward(self, tensordict):
        obs = tensordict["observation"]
        first = obs + self.shifts[tensordict["action"].long().argmax(-1)]
        at_origin = (obs == 0).all(-1, keepdim=True)
        tensordict["predicted_observation"] = torch.where(at_origin, first, 1.1 * obs)
        return tensordict


def test_long_horizons_use_a_bounded_random_search_covering_every_first_action():
    planner = NoveltyPlanner(
        FirstActionDynamics(SHIFTS), fitted(RollingGaussianDensity), OneHot(3), horizon=10, max_sequences=64
    )
    sequences = planner._action_sequences()
    assert sequences.shape == (63, 10)
    assert torch.equal(torch.bincount(sequences[:, 0]), torch.tensor([21, 21, 21]))
    assert not torch.equal(planner._action_sequences(), sequences)  # drawn afresh at each call
    td = planner(TensorDict({"observation": torch.zeros(5, 2)}, [5]))
    assert (td["action"].long().argmax(-1) == 2).all()  # only the first action decides where it ends


def test_exhaustive_sequences_start_with_action_index_modulo_num_actions():
    planner = NoveltyPlanner(ShiftDynamics(SHIFTS), fitted(RollingGaussianDensity), OneHot(3), horizon=3)
    sequences = planner._action_sequences()
    assert sequences.shape == (27, 3)
    assert len({tuple(row) for row in sequences.tolist()}) == 27
    assert torch.equal(sequences[:, 0], torch.arange(27) % 3)
    assert planner._action_sequences() is sequences  # enumerated once
    assert not any("sequences" in key for key in planner.state_dict())  # checkpoints unchanged
