"""The components on a user's own EnvBase: a Discrete observation (TorchRL's one-hot integers), two categorical variables (a MultiOneHot) and a Composite of two entries."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torchrl.data import Bounded, Composite, MultiOneHot, OneHot, Unbounded
from torchrl.envs import CatTensors, DTypeCastTransform, EnvBase, TransformedEnv
from torchrl.envs.utils import RandomPolicy

from torchrl_mbe import DynamicsLoss, DynamicsModel, NoveltyPlanner
from torchrl_mbe.modules import novelty

CELLS = 6
SCORERS = (
    novelty.RollingGaussianDensity,
    novelty.DiagonalGaussianDensity,
    novelty.GaussianKernelNovelty,
    novelty.KNearestNovelty,
    novelty.KernelDensityNovelty,
)


class Chain(EnvBase):
    """A chain of cells, left or right each step; the cell one-hot as integers (as TorchRL reads a gymnasium Discrete).

    With ``rooms``, beside a position; with ``colours``, beside a colour that cycles each step
    (two categorical variables: a ``MultiOneHot``, as TorchRL reads a gymnasium ``MultiDiscrete``).
    """

    def __init__(self, rooms: bool = False, colours: int = 0) -> None:
        super().__init__(batch_size=())
        observation = {"cell": OneHot(CELLS, dtype=torch.int64)}
        if rooms:
            observation["position"] = Bounded(0.0, 1.0, shape=(1,))
        if colours:
            observation["cell"] = MultiOneHot([CELLS, colours], dtype=torch.int64)
        self.observation_spec = Composite(observation if rooms else {"observation": observation["cell"]})
        self.action_spec = OneHot(2, dtype=torch.int64)
        self.reward_spec = Unbounded(shape=(1,))
        self.rooms, self.colours, self.cell, self.colour = rooms, colours, 0, 0

    def _observation(self) -> dict:
        cell = torch.nn.functional.one_hot(torch.tensor(self.cell), CELLS)
        if self.colours:
            cell = torch.cat([cell, torch.nn.functional.one_hot(torch.tensor(self.colour), self.colours)])
        return {"cell": cell, "position": torch.tensor([self.cell / CELLS])} if self.rooms else {"observation": cell}

    def _reset(self, tensordict=None) -> TensorDict:
        self.cell = self.colour = 0
        done = torch.zeros(1, dtype=torch.bool)
        return TensorDict({**self._observation(), "done": done, "terminated": done.clone(), "truncated": done.clone()})

    def _step(self, tensordict: TensorDict) -> TensorDict:
        self.cell = min(max(self.cell + (1 if tensordict["action"].argmax() == 1 else -1), 0), CELLS - 1)
        self.colour = (self.colour + 1) % max(self.colours, 1)
        done = torch.zeros(1, dtype=torch.bool)
        return TensorDict(
            {
                **self._observation(),
                "reward": torch.zeros(1),
                "done": done,
                "terminated": done.clone(),
                "truncated": done.clone(),
            }
        )

    def _set_seed(self, seed) -> None:
        torch.manual_seed(seed)


def learn_from_random_walk(env: EnvBase, dynamics: DynamicsModel) -> TensorDict:
    """Trains ``dynamics`` on 400 random steps of ``env``; returns them."""
    transitions = env.rollout(400, RandomPolicy(env.action_spec), break_when_any_done=False)
    loss, optimizer = DynamicsLoss(dynamics), torch.optim.Adam(dynamics.parameters(), lr=1e-2)
    for _ in range(300):
        optimizer.zero_grad()
        loss(transitions)["loss_dynamics"].backward()
        optimizer.step()
    return transitions


@pytest.mark.parametrize("output", ["delta", "categorical"])
def test_a_discrete_observation_of_one_hot_integers_is_learned_and_planned_over_by_every_scorer(output):
    env = Chain()
    dynamics = DynamicsModel(env.observation_spec, env.action_spec, [32], output=output, normalize=output == "delta")
    transitions = learn_from_random_walk(env, dynamics)
    with torch.no_grad():
        predicted = dynamics(transitions.exclude("next").clone())["predicted_observation"]
    assert (
        predicted.argmax(-1) == transitions["next", "observation"].argmax(-1)
    ).float().mean() > 0.95  # integer inputs and targets
    for scorer in SCORERS:
        window = scorer(window=20)
        window.update(transitions["observation"][:20])  # integers, as the env gives them
        planned = NoveltyPlanner(dynamics, window, env.action_spec)(
            TensorDict({"observation": transitions["observation"][:4]}, [4])
        )
        assert planned["action"].shape == (4, 2) and torch.isfinite(planned["novelty_scores"]).all(), scorer.__name__


def test_two_categorical_variables_are_learned_each_by_its_own_softmax_and_planned_over_by_every_scorer():
    env = Chain(colours=3)
    dynamics = DynamicsModel(env.observation_spec, env.action_spec, [32], output="categorical", normalize=False)
    assert dynamics.groups == (CELLS, 3)  # read from the MultiOneHot spec
    transitions = learn_from_random_walk(env, dynamics)
    with torch.no_grad():
        predicted = dynamics(transitions.exclude("next").clone())["predicted_observation"]
    for predicted_part, next_part in zip(
        predicted.split([CELLS, 3], -1), transitions["next", "observation"].split([CELLS, 3], -1)
    ):
        assert (predicted_part.argmax(-1) == next_part.argmax(-1)).float().mean() > 0.95
    for scorer in SCORERS:
        window = scorer(window=20)
        window.update(transitions["observation"][:20])
        planned = NoveltyPlanner(dynamics, window, env.action_spec)(
            TensorDict({"observation": transitions["observation"][:4]}, [4])
        )
        assert planned["action"].shape == (4, 2) and torch.isfinite(planned["novelty_scores"]).all(), scorer.__name__


def test_a_composite_observation_of_two_entries_is_read_once_torchrls_cat_tensors_joins_them():
    env = TransformedEnv(Chain(rooms=True), DTypeCastTransform(torch.int64, torch.float32, in_keys=["cell"]))
    env.append_transform(CatTensors(in_keys=["cell", "position"], out_key="observation"))
    dynamics = DynamicsModel(env.observation_spec, env.action_spec, [32])
    assert dynamics.observation_size == CELLS + 1
    transitions = learn_from_random_walk(env, dynamics)
    with torch.no_grad():
        predicted = dynamics(transitions.exclude("next").clone())["predicted_observation"]
    assert (
        predicted[:, :CELLS].argmax(-1) == transitions["next", "observation"][:, :CELLS].argmax(-1)
    ).float().mean() > 0.95
