"""The value of novelty: a TD loss that carries the planner's predicted novelty back along the visited paths (deep model-based exploration)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar

import torch
from tensordict import NestedKey, TensorDict, TensorDictBase
from tensordict.nn import TensorDictModuleBase, TensorDictParams
from torchrl.data import TensorSpec
from torchrl.objectives import LossModule, distance_loss

from torchrl_mbe.modules.actions import action_indices
from torchrl_mbe.modules.networks import action_values
from torchrl_mbe.modules.planner import reachable_novelty

__all__ = ["NoveltyValueLoss"]


class NoveltyValueLoss(LossModule):
    """TD learning of ``U``, the discounted novelty of the rarest state reachable beyond an action.

    The paper's planner takes the action whose predicted next state is rarest. Deep
    model-based exploration takes the action towards the rarest state *reachable*: it
    scores action ``a`` in state ``s`` by ``S(s, a) = max(n(s, a), U(s, a))``
    (:func:`~torchrl_mbe.modules.planner.reachable_novelty`). Here ``n(s, a)`` is the
    planner's novelty of the predicted next state ``D(s, a)``
    (:meth:`~torchrl_mbe.NoveltyPlanner.action_scores`), and ``U(s, a)`` is learned on
    visited one-step transitions ``(s, a, s')`` towards

        ``gamma * (1 - terminated') * max_a' S_target(s', a')``

    The maximum runs over every action of ``s'``, tried or not. The model scores an
    untried action's next state, so the novelty at the frontier of the visited states
    reaches the states that lead there, with no optimistic initialization (a learned
    intrinsic reward gives an untried action no such value). ``n`` is computed when the
    batch is sampled, from the scorer's current counts or window, so no stored bonus
    goes stale.

    The value network reads ``observation`` and writes one value per action under its
    only out key. Its target parameters are TorchRL's (``target_value_network_params``),
    updated with :class:`~torchrl.objectives.HardUpdate` or
    :class:`~torchrl.objectives.SoftUpdate`. For a population's networks (batches
    ``[*B, M]``), ``loss_novelty_value`` is ``[M]``, one mean per member.

    Args:
        value_network (TensorDictModuleBase): ``U``, observation to one value per action.
        action_novelty (callable): ``n``, observations ``(*batch, F)`` to ``(*batch, num_actions)``
            (a planner's ``action_scores``); it is called without gradients.
        action_spec (TensorSpec): how the batch's actions are encoded.

    Keyword Args:
        gamma (float): the discount of novelty. Defaults to ``0.99``.
        loss_function (str): ``"l2"``, ``"l1"`` or ``"smooth_l1"``. Defaults to ``"l2"``.
        num_members (int, optional): the population size ``M``.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from tensordict.nn import TensorDictModule
        >>> from torchrl.data import OneHot
        >>> from torchrl.modules import MLP
        >>> from torchrl_mbe.objectives import NoveltyValueLoss
        >>> value = TensorDictModule(MLP(in_features=2, out_features=3, num_cells=[8]), ["observation"], ["novelty_value"])
        >>> loss = NoveltyValueLoss(value, lambda states: torch.ones(*states.shape[:-1], 3), OneHot(3), gamma=0.5)
        >>> batch = TensorDict({
        ...     "observation": torch.randn(4, 2), "action": OneHot(3).rand((4,)),
        ...     "successor_observation": torch.randn(4, 2), "successor_terminated": torch.ones(4, 1, dtype=torch.bool)}, [4])
        >>> loss(batch)["target_novelty_value"]  # every successor terminal: nothing beyond it
        tensor(0.)
    """

    @dataclass
    class _AcceptedKeys:
        """Batch keys read by the loss (renamable with ``set_keys``).

        Attributes:
            observation (NestedKey): the state. Defaults to ``"observation"``.
            action (NestedKey): the action taken. Defaults to ``"action"``.
            successor (NestedKey): the state one step later. Defaults to ``"successor_observation"``.
            successor_terminated (NestedKey): whether that state ended the episode.
                Defaults to ``"successor_terminated"``.
        """

        observation: NestedKey = "observation"
        action: NestedKey = "action"
        successor: NestedKey = "successor_observation"
        successor_terminated: NestedKey = "successor_terminated"

    default_keys = _AcceptedKeys
    out_keys: ClassVar[list[str]] = ["loss_novelty_value", "target_novelty_value"]
    value_network: TensorDictModuleBase
    value_network_params: TensorDictParams
    target_value_network_params: TensorDictParams

    def __init__(
        self,
        value_network: TensorDictModuleBase,
        action_novelty: Callable[[torch.Tensor], torch.Tensor],
        action_spec: TensorSpec,
        *,
        gamma: float = 0.99,
        loss_function: str = "l2",
        num_members: int | None = None,
    ) -> None:
        super().__init__()
        if not 0.0 <= gamma < 1.0:
            raise ValueError(f"gamma must be in [0, 1) (novelty never ends, so 1 would not converge), got {gamma}.")
        self.convert_to_functional(value_network, "value_network", create_target_params=True)
        self.action_novelty = action_novelty
        self.action_spec = action_spec
        self.gamma = float(gamma)
        self.loss_function = loss_function
        self.num_members = num_members

    def _forward_value_estimator_keys(self, **kwargs) -> None:
        """No value estimator: the target is the loss's own."""

    @property
    def in_keys(self) -> list[NestedKey]:
        keys = self.tensor_keys
        return [keys.observation, keys.action, keys.successor, keys.successor_terminated]

    def values(self, observation: torch.Tensor, params: TensorDictBase) -> torch.Tensor:
        """``U(observation, .)`` under ``params``, ``(*batch, num_actions)``."""
        with params.to_module(self.value_network):
            return action_values(self.value_network, observation)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        keys = self.tensor_keys
        with torch.no_grad():
            successor = tensordict.get(keys.successor)
            beyond = reachable_novelty(
                self.action_novelty(successor), self.values(successor, self.target_value_network_params)
            )
            continues = ~tensordict.get(keys.successor_terminated).squeeze(-1)
            target = self.gamma * continues * beyond.amax(-1)
        values = self.values(tensordict.get(keys.observation), self.value_network_params)
        action = action_indices(tensordict.get(keys.action), self.action_spec)
        chosen = values.gather(-1, action.unsqueeze(-1)).squeeze(-1)
        loss = distance_loss(chosen, target, self.loss_function)
        return TensorDict(
            {"loss_novelty_value": self._mean(loss), "target_novelty_value": self._mean(target)}, batch_size=[]
        )

    def _mean(self, values: torch.Tensor) -> torch.Tensor:
        """The mean, or a population's ``[*B, M]`` values' mean per member, ``[M]``."""
        if self.num_members is None:
            return values.mean()
        return values.reshape(-1, self.num_members).mean(0)
