"""A tabular dynamics model of a one-hot observation: each (state, action) pair's observed successor, optimistic where untried."""

from __future__ import annotations

import torch
from tensordict import NestedKey, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.data import TensorSpec

from torchrl_mbe.modules.actions import action_indices, discrete_action_spec, num_discrete_actions
from torchrl_mbe.modules.observations import categorical_groups, flat_observation_size

__all__ = ["TransitionTable"]

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
    def write(self, observation: torch.Tensor, action: torch.Tensor, next_observation: torch.Tensor) -> None:
        """Stores the successor of each transition (``[*B, F]`` observations, ``action`` as the spec encodes it)."""
        state, successor = self.cell_index(observation), self.cell_index(next_observation)
        action = action_indices(action, self.action_spec).expand(state.shape)
        from_cell = state < self.observation_size
        self.successor[state[from_cell], action[from_cell]] = successor[from_cell]
        self.seen[state] = True
        self.seen[successor] = True

    def predict(self, observation: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """The successor's one-hot code after each pair, ``observation.shape``; the mean code of the unseen states where untried."""
        size = self.observation_size
        state = self.cell_index(observation)
        action = action_indices(action, self.action_spec).expand(state.shape)
        successor = self.successor[state.clamp(max=size - 1), action].masked_fill(state == size, size)
        unseen = ~self.seen[:size]
        optimistic = (unseen if unseen.any() else torch.ones_like(unseen)).to(observation.dtype)
        optimistic = optimistic / optimistic.sum()
        untried = (successor == UNTRIED).unsqueeze(-1)
        codes = observation.new_zeros((*successor.shape, size + 1)).scatter_(
            -1, successor.clamp(min=0).unsqueeze(-1), 1
        )
        return torch.where(untried, optimistic, codes[..., :size])  # the last entry, a successor of zeros, dropped

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        observation_key, action_key = self.in_keys
        prediction = self.predict(tensordict.get(observation_key), tensordict.get(action_key))
        return tensordict.set(self.out_keys[0], prediction)
