"""A tabular dynamics model of a one-hot observation (each (state, action) pair's observed successor, optimistic where untried), and the value of novelty computed on it."""

from __future__ import annotations

from typing import ClassVar

import torch
from tensordict import NestedKey, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.data import TensorSpec

from torchrl_mbe.modules.actions import action_indices, discrete_action_spec, num_discrete_actions
from torchrl_mbe.modules.novelty import RollingWindowNovelty
from torchrl_mbe.modules.observations import categorical_groups, flat_observation_size
from torchrl_mbe.modules.planner import reachable_novelty

__all__ = ["TableActionValue", "TableNoveltyValue", "TransitionTable"]

UNTRIED = -1


class TransitionTable(TensorDictModuleBase):
    """``D(s, a)`` of a one-hot observation read by its hot index: the successor last observed after ``a`` in ``s``.

    A learned model for states that are cells (DeepSea's grid, gymnasium's ``Discrete``
    states). :meth:`write` stores each transition's successor; a pair tried once is then
    predicted exactly on a deterministic task (on a stochastic one, its latest outcome).
    An untried pair is predicted optimistically, as a state the table has never seen: the
    mean of the one-hot codes of every such state (of all states once each is seen). A
    novelty scorer rates that prediction as new (a visit count's bonus is 1), so the
    planner tries each pair once, and :class:`~torchrl_mbe.objectives.NoveltyValueLoss`
    carries that optimism back along the paths that lead to untried pairs (R-max's
    optimism, Brafman & Tennenholtz 2002, in the planner's terms).

    A network's prediction of an untried pair is its generalization from the tried ones;
    on DeepSea it lands on visited cells as often as on new ones, which the planner cannot
    tell apart. The table costs one lookup a prediction and nothing to train. An
    observation of zeros (DeepSea's after its last row) is a state with no successors:
    its predictions, and a successor of zeros, are zeros.

    Args:
        observation_size (int or TensorSpec): the number of cells, or a one-hot spec of
            one group (``OneHot``), or a ``Composite`` holding it under ``observation_key``.
        action_spec (OneHot, Categorical or Composite): how ``action`` is encoded.

    Keyword Args:
        observation_key (NestedKey): defaults to ``"observation"``.
        action_key (NestedKey): defaults to ``"action"``.
        out_key (NestedKey): defaults to ``"predicted_observation"``.
        device (torch.device, optional): where the table lives.

    Examples:
        >>> import torch
        >>> from torchrl.data import Categorical
        >>> from torchrl_mbe import TransitionTable
        >>> cells = torch.eye(4)
        >>> table = TransitionTable(4, Categorical(2))
        >>> table.write(cells[[0]], torch.tensor([1]), cells[[2]])  # action 1 led from cell 0 to cell 2
        >>> table.predict(cells[[0, 0]], torch.tensor([1, 0]))  # the tried pair, then an untried one
        tensor([[0.0000, 0.0000, 1.0000, 0.0000],
                [0.0000, 0.5000, 0.0000, 0.5000]])
    """

    def __init__(
        self,
        observation_size: int | TensorSpec,
        action_spec: TensorSpec,
        *,
        observation_key: NestedKey = "observation",
        action_key: NestedKey = "action",
        out_key: NestedKey = "predicted_observation",
        device: torch.device | str | None = None,
    ) -> None:
        super().__init__()
        groups = categorical_groups(observation_size, observation_key)
        if len(groups) != 1:
            raise ValueError(
                f"TransitionTable reads one-hot states of one group (a OneHot spec); got {len(groups)} groups {groups}."
            )
        self.observation_size = size = flat_observation_size(observation_size, observation_key)
        self.action_spec = discrete_action_spec(action_spec, action_key)
        self.in_keys = [observation_key, action_key]
        self.out_keys = [out_key]
        num_actions = num_discrete_actions(self.action_spec)
        # the successor's cell index after each (cell, action); `size` for a successor of zeros, UNTRIED before a try
        self.register_buffer("successor", torch.full((size, num_actions), UNTRIED, dtype=torch.long, device=device))
        # every cell written as a state or a successor, and, last, the state of zeros
        self.register_buffer("seen", torch.zeros(size + 1, dtype=torch.bool, device=device))
        # the cells an episode ended on arriving at (a terminated transition's successor), and the state of zeros
        self.register_buffer("terminal", torch.zeros(size + 1, dtype=torch.bool, device=device))
        self.terminal[size] = True
        # the reward each pair last gave
        self.register_buffer("reward", torch.zeros(size, num_actions, device=device))

    def extra_repr(self) -> str:
        return f"observation_size={self.observation_size}, num_actions={self.successor.shape[-1]}"

    def cell_index(self, observation: torch.Tensor) -> torch.Tensor:
        """Each one-hot observation's hot index, ``observation.shape[:-1]``; ``observation_size`` for zeros.

        Anything else (a prediction mixing cells) is refused: the table predicts from states.
        """
        observation = observation.float()
        is_cell = (observation.amax(-1) == 1) & (observation.sum(-1) == 1)
        is_zeros = ~observation.any(-1)
        if not bool((is_cell | is_zeros).all()):
            raise ValueError(
                "TransitionTable predicts from one-hot states or zeros; got an observation that is neither "
                "(plan with horizon=1, or use DynamicsModel)."
            )
        return torch.where(is_cell, observation.argmax(-1), self.observation_size)

    @torch.no_grad()
    def write(
        self,
        observation: torch.Tensor,
        action: torch.Tensor,
        next_observation: torch.Tensor,
        terminated: torch.Tensor | None = None,
        reward: torch.Tensor | None = None,
    ) -> None:
        """Stores the successor of each transition (``[*B, F]`` observations, ``action`` as the spec encodes it).

        ``terminated`` (``[*B]`` or ``[*B, 1]``) marks the successors an episode ended on: nothing
        lies beyond them. ``reward`` (the same shape) is each pair's reward.
        """
        state, successor = self.cell_index(observation), self.cell_index(next_observation)
        action = action_indices(action, self.action_spec).expand(state.shape)
        from_cell = state < self.observation_size
        self.successor[state[from_cell], action[from_cell]] = successor[from_cell]
        self.seen[state] = True
        self.seen[successor] = True
        if terminated is not None:
            self.terminal[successor[terminated.reshape(state.shape)]] = True
        if reward is not None:
            self.reward[state[from_cell], action[from_cell]] = reward.reshape(state.shape)[from_cell].to(self.reward)

    def optimistic_code(self) -> torch.Tensor:
        """What an untried pair is predicted to reach, ``(observation_size,)``: the mean code of the states never seen (of all, once each is)."""
        unseen = ~self.seen[: self.observation_size]
        optimistic = (unseen if unseen.any() else torch.ones_like(unseen)).float()
        return optimistic / optimistic.sum()

    def predict(self, observation: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """The successor's one-hot code after each pair, ``observation.shape``; the mean code of the unseen states where untried."""
        size = self.observation_size
        state = self.cell_index(observation)
        action = action_indices(action, self.action_spec).expand(state.shape)
        successor = self.successor[state.clamp(max=size - 1), action].masked_fill(state == size, size)
        optimistic = self.optimistic_code().to(observation.dtype)
        untried = (successor == UNTRIED).unsqueeze(-1)
        codes = observation.new_zeros((*successor.shape, size + 1)).scatter_(
            -1, successor.clamp(min=0).unsqueeze(-1), 1
        )
        return torch.where(untried, optimistic, codes[..., :size])  # the last entry, a successor of zeros, dropped

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        observation_key, action_key = self.in_keys
        prediction = self.predict(tensordict.get(observation_key), tensordict.get(action_key))
        return tensordict.set(self.out_keys[0], prediction)


class TableValueIteration(TensorDictModuleBase):
    """Base class: action values solved on a :class:`TransitionTable` by value iteration, read by each observation's cell.

    :meth:`refresh` sweeps from zeros until nothing changes (at most one sweep a cell:
    sweep ``k`` knows every path of ``k`` steps, so a value ``N`` steps away reaches the
    start in ``N`` sweeps, where a learned one needs ``N`` target updates). A pair's value
    beyond it is ``gamma`` times its successor's value, 0 for an untried pair or a
    successor that ended an episode. Subclasses give each pair's own term
    (:meth:`pair_terms`), a state's value (:meth:`state_values`) and how a pair adds its
    term to what lies beyond (:meth:`backup`).

    Args:
        table (TransitionTable): the learned dynamics.

    Keyword Args:
        gamma (float): the discount, in ``[0, 1]`` (the sweeps stop after one a cell, so 1
            ends too). Defaults to ``0.99``.
        observation_key (NestedKey): defaults to ``"observation"``.
        out_key (NestedKey): defaults to the subclass's ``default_out_key``.
    """

    default_out_key: ClassVar[str]

    def __init__(
        self,
        table: TransitionTable,
        *,
        gamma: float = 0.99,
        observation_key: NestedKey = "observation",
        out_key: NestedKey | None = None,
    ) -> None:
        super().__init__()
        if not 0.0 <= gamma <= 1.0:
            raise ValueError(f"gamma must be in [0, 1], got {gamma}.")
        self.table = table
        self.gamma = float(gamma)
        self.in_keys = [observation_key]
        self.out_keys = [out_key or self.default_out_key]
        num_cells, num_actions = table.successor.shape
        # each cell's action values, and, last, the state of zeros' (nothing beyond it)
        self.register_buffer("values", torch.zeros(num_cells + 1, num_actions, device=table.successor.device))

    @torch.no_grad()
    def refresh(self) -> None:
        """Solves the values for the table (and the subclass's terms) as they are now."""
        successor = self.table.successor
        terms, tried = self.pair_terms(), successor != UNTRIED
        continues = tried & ~self.table.terminal[successor.clamp(min=0)]
        beyond = successor.clamp(min=0)
        values = torch.zeros_like(terms)
        for _ in range(successor.shape[0] + 1):  # a path visits each cell once at most
            state_values = torch.cat([self.state_values(terms, values), values.new_zeros(1)])  # zeros: nothing
            swept = self.backup(terms, tried, torch.where(continues, self.gamma * state_values[beyond], 0.0))
            if torch.equal(swept, values):
                break
            values = swept
        self.values[:-1] = values

    def pair_terms(self) -> torch.Tensor:
        """Each pair's own term, ``(observation_size, num_actions)``."""
        raise NotImplementedError

    def state_values(self, terms: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
        """Each cell's value from its pairs' terms and values, ``(observation_size,)``."""
        raise NotImplementedError

    def backup(self, terms: torch.Tensor, tried: torch.Tensor, beyond: torch.Tensor) -> torch.Tensor:
        """Each pair's value from its term and the discounted value beyond it."""
        raise NotImplementedError

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        observation = tensordict.get(self.in_keys[0])
        return tensordict.set(self.out_keys[0], self.values[self.table.cell_index(observation)])


class TableNoveltyValue(TableValueIteration):
    """``U`` computed on a :class:`TransitionTable` by value iteration: the discounted novelty of the rarest state reachable beyond each action.

    The fixed point that :class:`~torchrl_mbe.objectives.NoveltyValueLoss` learns from
    replayed transitions, solved over every cell of the table at once:

        ``U(s, a) = gamma * max_a' max(n(s', a'), U(s', a'))``

    for a tried pair whose successor ``s'`` did not end an episode, and 0 otherwise.
    ``n(s', a')`` is the scorer's novelty of the table's prediction (the optimistic code
    of an untried pair, which a count bonus scores 1). :meth:`refresh` solves it for the
    table and the scorer as they are now (the planning explorer calls it after writing
    each collected batch); the forward pass reads each observation's row.

    Args:
        table (TransitionTable): the learned dynamics.
        novelty (RollingWindowNovelty): the planner's scorer; a scorer with a batch of
            windows (one per env) is averaged over them.

    Keyword Args:
        gamma, observation_key, out_key: as :class:`TableValueIteration`'s
            (``out_key`` defaults to ``"novelty_value"``).

    Examples:
        >>> import torch
        >>> from torchrl.data import Categorical
        >>> from torchrl_mbe import TableNoveltyValue, TransitionTable, VisitCounts
        >>> cells = torch.eye(4)  # a chain 0 -> 1 -> 2 under both actions; cell 2's untried, cell 3 never seen
        >>> table, counts = TransitionTable(4, Categorical(2)), VisitCounts(4)
        >>> table.write(cells[[0, 0, 1, 1]], torch.tensor([0, 1, 0, 1]), cells[[1, 1, 2, 2]])
        >>> counts.update(cells[[0, 1, 2, 2, 2]])
        >>> value = TableNoveltyValue(table, counts, gamma=0.5)
        >>> value.refresh()  # an untried pair scores 1: cell 1 is one step before them, cell 0 two
        >>> value.values[:3]
        tensor([[0.2500, 0.2500],
                [0.5000, 0.5000],
                [0.0000, 0.0000]])
    """

    default_out_key = "novelty_value"

    def __init__(self, table: TransitionTable, novelty: RollingWindowNovelty, **kwargs) -> None:
        super().__init__(table, **kwargs)
        self.novelty = novelty

    def pair_terms(self) -> torch.Tensor:
        """``n(s, a)`` of every pair: the scorer's novelty of the table's prediction."""
        table, scorer = self.table, self.novelty
        size = table.observation_size
        cells = scorer.cell_scores().reshape(-1, size).mean(0)
        others = torch.stack([cells.new_zeros(size), table.optimistic_code().to(cells)])  # zeros, an untried pair's
        batch = scorer.batch_shape
        others = scorer.score(others.view(2, *[1] * len(batch), size).expand(2, *batch, size)).reshape(2, -1).mean(-1)
        per_successor = torch.cat([cells, others[:1]])  # indexed by the successor's cell, zeros last
        successor = table.successor
        return torch.where(successor == UNTRIED, others[1], per_successor[successor.clamp(min=0)])

    def state_values(self, terms: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
        return reachable_novelty(terms, values).amax(-1)

    def backup(self, terms: torch.Tensor, tried: torch.Tensor, beyond: torch.Tensor) -> torch.Tensor:
        return beyond  # a pair's own novelty is the planner's n, scored beside U


class TableActionValue(TableValueIteration):
    """``Q(s, a)`` of the rewards a :class:`TransitionTable` recorded, solved by value iteration.

    ``Q(s, a) = r(s, a) + gamma * max_a' Q(s', a')`` for a tried pair (``r`` its last
    reward; nothing beyond a successor that ended an episode), 0 for an untried one. Once
    a reward is found, the path to it is valued at once, all the way back; an exploring
    step that weighs these values (``value_weight``) returns to it while the Q-network
    is still learning it.

    Args:
        table (TransitionTable): the learned dynamics and rewards.

    Keyword Args:
        gamma, observation_key, out_key: as :class:`TableValueIteration`'s
            (``out_key`` defaults to ``"table_action_value"``).

    Examples:
        >>> import torch
        >>> from torchrl.data import Categorical
        >>> from torchrl_mbe import TableActionValue, TransitionTable
        >>> cells = torch.eye(3)  # 0 -> 1 -> 2 by action 1, which pays 1 on arriving in cell 2
        >>> table = TransitionTable(3, Categorical(2))
        >>> table.write(cells[[0, 1]], torch.tensor([1, 1]), cells[[1, 2]], reward=torch.tensor([0.0, 1.0]))
        >>> value = TableActionValue(table, gamma=0.9)
        >>> value.refresh()
        >>> value.values[:2]
        tensor([[0.0000, 0.9000],
                [0.0000, 1.0000]])
    """

    default_out_key = "table_action_value"

    def pair_terms(self) -> torch.Tensor:
        return self.table.reward

    def state_values(self, terms: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
        return values.amax(-1)

    def backup(self, terms: torch.Tensor, tried: torch.Tensor, beyond: torch.Tensor) -> torch.Tensor:
        return torch.where(tried, terms + beyond, 0.0)
