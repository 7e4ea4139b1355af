"""bsuite's DeepSea in torch: ``num_envs`` copies of one N x N exploration chain, stepped together.

A transcription of ``bsuite/environments/deep_sea.py`` (google-deepmind/bsuite,
last changed in commit 6d8f649, identical in the bsuite 0.3.6 release) as a
batched TorchRL env. bsuite's experiment (``bsuite/experiments/deep_sea/``) runs
sizes N = 10, 12, ..., 50 with ``mapping_seed=42`` for 10,000 episodes each; its
score counts a size as solved at the first episode where fewer than 90% of the
episodes so far were "bad" (left the diagonal), and as beating dithering if that
happens before episode ``2**N + 100``.
"""

from __future__ import annotations

import numbers
from collections.abc import Sequence

import numpy as np
import torch
from tensordict import NestedKey, TensorDictBase
from torchrl.data import OneHot, TensorSpec

from torchrl_mbe.envs.batched import BatchedTorchEnv
from torchrl_mbe.modules.dynamics import ExactDynamics

__all__ = ["BatchedDeepSeaEnv", "DeepSeaDynamics", "deepsea_action_mapping"]


def deepsea_action_mapping(size: int, mapping_seed: int | None = 42) -> torch.Tensor:
    """Which action moves right in each cell, ``(size, size)`` int64: bsuite's draw, or all ones for ``mapping_seed=None``.

    Examples:
        >>> from torchrl_mbe.envs.deepsea import deepsea_action_mapping
        >>> deepsea_action_mapping(3).tolist()
        [[0, 1, 1], [1, 0, 0], [0, 1, 1]]
    """
    if mapping_seed is None:
        return torch.ones(size, size, dtype=torch.int64)
    return torch.as_tensor(np.random.RandomState(mapping_seed).binomial(1, 0.5, [size, size]), dtype=torch.int64)


class DeepSeaDynamics(ExactDynamics):
    """DeepSea's exact dynamics (the deterministic variant) as a dynamics module: the oracle of ``dynamics=oracle``.

    It predicts what :class:`BatchedDeepSeaEnv` of the same ``size`` and
    ``mapping_seed`` returns: the one-hot cell one row down and one column to the
    side the action leads in the current cell, all zeros after the last row.
    With it the planner's choices depend on the novelty scorer alone, not on how
    well a model has learned the per-cell action mapping.

    Args:
        action_spec (OneHot, Categorical or Composite): how ``action`` is encoded.

    Keyword Args:
        size (int): the grid's side N. Defaults to 10.
        mapping_seed (int): bsuite's mapping seed. Defaults to 42.
        **keys: the keys of :class:`~torchrl_mbe.modules.dynamics.ExactDynamics`.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl.data import Categorical
        >>> from torchrl_mbe.envs.deepsea import DeepSeaDynamics
        >>> oracle = DeepSeaDynamics(Categorical(2), size=3)
        >>> start = torch.eye(9)[0]  # the top-left cell
        >>> td = TensorDict({"observation": start.expand(2, 9), "action": torch.tensor([0, 1])}, [2])
        >>> oracle(td)["predicted_observation"].argmax(-1).tolist()  # action 0 moves right here, to cell (1, 1)
        [4, 3]
    """

    def __init__(self, action_spec: TensorSpec, *, size: int = 10, mapping_seed: int = 42, **keys: NestedKey) -> None:
        super().__init__(action_spec, **keys)
        self.size = int(size)
        self.register_buffer(
            "action_mapping",
            deepsea_action_mapping(self.size, mapping_seed).to(self.action_spec.device),
            persistent=False,
        )

    def step(self, observation: torch.Tensor, action_index: torch.Tensor) -> torch.Tensor:
        cell = observation.argmax(-1)
        row, column = cell // self.size, cell % self.size
        right = action_index == self.action_mapping[row, column]
        column = torch.where(right, column + 1, column - 1).clamp(0, self.size - 1)
        on_grid = (observation.sum(-1) > 0) & (row + 1 < self.size)  # else the null observation after the last row
        following = torch.nn.functional.one_hot((row + 1).clamp_max(self.size - 1) * self.size + column, self.size**2)
        return following.to(observation.dtype) * on_grid.unsqueeze(-1)


class BatchedDeepSeaEnv(BatchedTorchEnv):
    """``num_envs`` copies of bsuite's ``DeepSea(size)`` stepped together as torch tensors.

    The agent starts in the top-left cell of an N x N grid and falls one row per
    step; each step moves it one column left or right (clipped at the edges), so an
    episode lasts exactly N steps and ends ``terminated``. As in bsuite:

    * which action moves right is drawn per cell: ``action_mapping`` is
      ``numpy.random.RandomState(mapping_seed).binomial(1, 0.5, [N, N])``, and
      action ``a`` in cell ``(row, column)`` moves right iff
      ``a == action_mapping[row, column]`` (bsuite's ``_action_mapping``, the same
      numbers for the same ``mapping_seed``);
    * every right move costs ``unscaled_move_cost / N``; a right move from the last
      column (reachable only at the last row, by N right moves) earns the treasure,
      +1. The optimal return is ``1 - unscaled_move_cost`` (0.99); every other
      episode returns between ``-unscaled_move_cost`` and 0;
    * the observation is the grid, one-hot at the agent's cell, flattened to
      ``N * N`` float32 values (row-major: cell ``(row, column)`` is entry
      ``row * N + column``); after the last step it is all zeros (bsuite's null
      observation of row N). Actions are one-hot int64 of 2;
    * ``deterministic=False`` is bsuite's stochastic variant: a right move fails
      (the column stays) with probability 1/N, still paying its cost, and N(0, 1)
      noise is added to the reward of the last row's first and last cells.

    All copies share one mapping: they are one MDP, as a single agent collecting
    from a batch needs (its observation does not reveal the mapping). A run with
    another MDP, e.g. one population member per mapping, builds its own env with
    its own ``mapping_seed``. The mapping depends on ``mapping_seed`` alone, never on
    :meth:`set_seed`, so the evaluation envs ``make_env`` builds with other seeds
    play the same MDP.

    bsuite's ``bad episode`` count (its score) is not kept: in the deterministic
    variant an episode is bad iff it misses the treasure, i.e. iff its last reward
    is not positive.

    Resets may be partial (a ``"_reset"`` mask restarts only those copies). A
    finished copy (row N) stays put if stepped again, with reward 0, as
    ``rollout(..., break_when_all_done=True)`` does to copies that finished first.
    ``state_dict`` holds the positions and the generator's state (see
    :class:`~torchrl_mbe.envs.batched.BatchedTorchEnv`), not the mapping: the
    arguments fix it.

    Args:
        num_envs (int or tuple of int): number of copies (``batch_size`` ``(num_envs,)``), or the batch shape.

    Keyword Args:
        size (int): N, the grid's side. Defaults to 10 (bsuite's ``deep_sea/0``).
        mapping_seed (int): seeds the action mapping. Defaults to 42 (bsuite's sweep).
        deterministic (bool): bsuite's default ``True``; ``False`` for the stochastic variant.
        unscaled_move_cost (float): the total cost of N right moves. Defaults to 0.01.
        randomize_actions (bool): ``False`` is bsuite's debug mode: action 1 moves
            right everywhere. Defaults to ``True``.
        seed (int, optional): seeds the stochastic variant's randomness. Defaults to a
            seed drawn from torch's global generator.
        device (torch.device): where the env's tensors live. Defaults to CPU.

    Attributes:
        action_mapping (Tensor): the int64 ``(N, N)`` action that moves right in each cell.
        row, column (Tensor): the int64 ``(*batch_size)`` position of every copy.

    Examples:
        >>> import torch
        >>> from torchrl.envs.utils import check_env_specs
        >>> from torchrl_mbe.envs.deepsea import BatchedDeepSeaEnv
        >>> env = BatchedDeepSeaEnv(4, size=10)
        >>> check_env_specs(env)
        >>> def always_right(td):  # the action the mapping sends right, in every copy's cell
        ...     return td.set("action", torch.nn.functional.one_hot(env.action_mapping[env.row, env.column], 2))
        >>> rollout = env.rollout(100, always_right)
        >>> rollout.shape, rollout["observation"].shape
        (torch.Size([4, 10]), torch.Size([4, 10, 100]))
        >>> rollout["next", "reward"].sum(1).squeeze(-1)
        tensor([0.9900, 0.9900, 0.9900, 0.9900])
        >>> bool(rollout["next", "terminated"][:, -1].all()), rollout["next", "observation"][:, -1].sum().item()
        (True, 0.0)
    """

    num_actions = 2

    def __init__(
        self,
        num_envs: int | Sequence[int],
        *,
        size: int = 10,
        mapping_seed: int = 42,
        deterministic: bool = True,
        unscaled_move_cost: float = 0.01,
        randomize_actions: bool = True,
        seed: int | None = None,
        device: torch.device | str = "cpu",
    ) -> None:
        if isinstance(size, bool) or not isinstance(size, numbers.Integral) or size < 1:
            raise ValueError(f"DeepSea's size must be an integer >= 1 (bsuite's sweep: 10, 12, ..., 50), got {size!r}.")
        super().__init__(num_envs, seed=seed, device=device)
        self.size = int(size)
        self.deterministic = bool(deterministic)
        self.unscaled_move_cost = float(unscaled_move_cost)
        cells = self.size**2
        # One-hot cells (all zeros once the last row is left behind): what makes an explorer choose a categorical model.
        self._make_spec(OneHot(cells, shape=(*self.batch_size, cells), dtype=torch.float32, device=self.device))
        # The MDP, fixed by the arguments, is no part of state_dict; the positions are.
        mapping = deepsea_action_mapping(self.size, mapping_seed if randomize_actions else None).to(self.device)
        self.register_buffer("action_mapping", mapping, persistent=False)
        self.register_buffer("cells", torch.arange(cells, device=self.device), persistent=False)
        self.register_buffer("row", torch.zeros(self.batch_size, dtype=torch.int64, device=self.device))
        self.register_buffer("column", torch.zeros(self.batch_size, dtype=torch.int64, device=self.device))

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        reset = None if tensordict is None else tensordict.get("_reset", None)
        if reset is None:
            self.row.zero_()
            self.column.zero_()
        else:
            reset = reset.reshape(self.batch_size)
            self.row.masked_fill_(reset, 0)
            self.column.masked_fill_(reset, 0)
        return self._observation_and_flags()

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        last = self.size - 1
        live = self.row <= last  # finished copies (row N) stay put
        action = tensordict.get("action").argmax(-1)
        right = live & (action == self.action_mapping[self.row.clamp(max=last), self.column])
        reward = (right & (self.column == last)).to(torch.float32)  # the treasure
        moves_right = right
        if not self.deterministic:
            chain_end = live & (self.row == last) & ((self.column == 0) | (self.column == last))
            reward += chain_end * torch.randn(self.batch_size, generator=self._generator).to(self.device)
            moves_right = right & (
                torch.rand(self.batch_size, generator=self._generator).to(self.device) > 1 / self.size
            )
        reward -= right * (self.unscaled_move_cost / self.size)
        move = moves_right.long() - (live & ~right).long()  # +1 right, -1 left, 0 when a right move fails
        self.column.copy_((self.column + move).clamp(0, last))
        self.row.add_(live.long())
        output = self._observation_and_flags()
        output.set("reward", reward.unsqueeze(-1))
        return output

    def _observation_and_flags(self) -> TensorDictBase:
        position = (self.row * self.size + self.column).unsqueeze(-1)  # >= N * N at row N: no cell, all zeros
        terminated = (self.row == self.size).unsqueeze(-1)
        return self._output((self.cells == position).to(torch.float32), terminated, torch.zeros_like(terminated))
