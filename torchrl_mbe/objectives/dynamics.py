"""Losses: the dynamics network's regression loss as a TorchRL ``LossModule``."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch
from tensordict import NestedKey, TensorDict, TensorDictBase, unravel_key
from tensordict.nn import TensorDictModuleBase
from torchrl.objectives import LossModule

__all__ = ["DynamicsLoss"]


class DynamicsLoss(LossModule):
    """Mean squared error between the predicted and the observed next observation.

    Algorithm 1's dynamics step: gradient descent on ``(s_{j+1} - D(s_j, a_j))^2``.
    The dynamics module may be any TensorDictModule reading an observation and an
    action and writing one prediction (its own ``in_keys``/``out_keys``); this loss
    reads the batch under its :attr:`tensor_keys` and feeds the module, so the
    batch's keys can be renamed with :meth:`set_keys` without touching the module.

    A categorical :class:`~torchrl_mbe.DynamicsModel` (``output="categorical"``) is
    trained with the cross-entropy ``-sum_i s'_i log softmax(logits)_i`` instead (a next
    observation of zeros, DeepSea's after its last row, is the last class), plus, with a
    prior, the squared norm of its offset, which the network learns to cancel
    (:meth:`~torchrl_mbe.DynamicsModel.categorical_parts`).

    When the module has a ``delta_scale`` buffer (as :class:`~torchrl_mbe.DynamicsModel`
    does) the error of each dimension is divided by it, so that every dimension
    weighs the same whatever its units (mbrl-lib trains in normalized units too);
    ``loss_dynamics`` is that normalized MSE and ``mse_dynamics`` (detached) the
    raw one, in observation units. For a population model (``num_members`` M, batches
    ``[*B, M]``) both are ``[M]``, one mean per member: their sum is what trains,
    so each member's gradient is its own single model's.

    A module with a ``fit_normalization`` method whose ``normalization_fitted`` is
    ``False`` (a fresh :class:`~torchrl_mbe.DynamicsModel`) has its statistics fitted
    on the first batch this loss is called on with gradients enabled, that is, the
    first it trains on; calls under ``torch.no_grad()`` (validation errors) never fit.
    Start training after a few hundred frames, as any DQN's learning start, or call
    ``fit_normalization`` yourself on more data first.

    Args:
        dynamics (TensorDictModuleBase): the dynamics network.

    Keyword Args:
        normalize (bool): divide errors by the module's ``delta_scale`` when it
            has one. Defaults to ``True``.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl.data import OneHot
        >>> from torchrl_mbe import DynamicsLoss, DynamicsModel
        >>> loss = DynamicsLoss(DynamicsModel(2, OneHot(3)))
        >>> batch = TensorDict({
        ...     "observation": torch.randn(8, 2), "action": OneHot(3).rand((8,)),
        ...     ("next", "observation"): torch.randn(8, 2)}, [8])
        >>> sorted(loss(batch).keys())
        ['loss_dynamics', 'mse_dynamics']
        >>> loss.dynamics.normalization_fitted  # fitted on that first batch
        True
        >>> loss.set_keys(observation="obs")  # read the batch's "obs" instead
    """

    @dataclass
    class _AcceptedKeys:
        """Batch keys read by the loss (renamable with ``set_keys``).

        Attributes:
            observation (NestedKey): current observation. Defaults to ``"observation"``.
            action (NestedKey): action taken. Defaults to ``"action"``.
            next_observation (NestedKey): observed next observation.
                Defaults to ``("next", "observation")``.
        """

        observation: NestedKey = "observation"
        action: NestedKey = "action"
        next_observation: NestedKey = ("next", "observation")

    default_keys = _AcceptedKeys
    out_keys: ClassVar[list[str]] = ["loss_dynamics", "mse_dynamics"]

    def __init__(self, dynamics: TensorDictModuleBase, *, normalize: bool = True) -> None:
        super().__init__()
        if len(dynamics.in_keys) != 2 or len(dynamics.out_keys) != 1:
            raise ValueError(
                "The dynamics module must read exactly (observation, action) and write one prediction; "
                f"got in_keys={dynamics.in_keys}, out_keys={dynamics.out_keys}."
            )
        self.dynamics = dynamics
        self.normalize = normalize

    def _forward_value_estimator_keys(self, **kwargs) -> None:
        """No value estimator: nothing to forward."""

    @property
    def in_keys(self) -> list[NestedKey]:
        keys = self.tensor_keys
        return [keys.observation, keys.action, keys.next_observation]

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        keys = self.tensor_keys
        observation_key, action_key = self.dynamics.in_keys
        inputs = TensorDict(
            {observation_key: tensordict.get(keys.observation), action_key: tensordict.get(keys.action)},
            batch_size=tensordict.batch_size,
        )
        next_observation = tensordict.get(keys.next_observation)
        if torch.is_grad_enabled() and getattr(self.dynamics, "normalization_fitted", True) is False:
            next_key = unravel_key(("next", observation_key))
            self.dynamics.fit_normalization(
                inputs.copy().set(next_key, next_observation), next_observation_key=next_key
            )
        num_members = getattr(self.dynamics, "num_members", None)
        if getattr(self.dynamics, "output", "delta") == "categorical":
            return self._categorical_losses(
                inputs.get(observation_key), inputs.get(action_key), next_observation, num_members
            )
        prediction = self.dynamics(inputs).get(self.dynamics.out_keys[0])
        error = prediction - next_observation
        scale = getattr(self.dynamics, "delta_scale", None) if self.normalize else None
        normalized_error = error if scale is None else error / scale
        return TensorDict(
            {
                "loss_dynamics": _mean(normalized_error.square(), num_members),
                "mse_dynamics": _mean(error.detach().square(), num_members),
            },
            batch_size=[],
        )

    def _categorical_losses(
        self, observation: torch.Tensor, action: torch.Tensor, next_observation: torch.Tensor, num_members: int | None
    ) -> TensorDict:
        logits, offset = self.dynamics.categorical_parts(observation, action)
        loss = -self.dynamics.categorical_log_likelihood(logits, next_observation)  # each group's cross-entropy, summed
        if offset is not None:
            loss = loss + offset.square().sum(-1, keepdim=True)
        error = self.dynamics.categorical_prediction(logits, offset).detach() - next_observation
        return TensorDict(
            {"loss_dynamics": _mean(loss, num_members), "mse_dynamics": _mean(error.square(), num_members)},
            batch_size=[],
        )


def _mean(losses: torch.Tensor, num_members: int | None) -> torch.Tensor:
    """The mean, or for a population's ``[*B, M, F]`` losses one mean per member, ``[M]`` (summed, each member's gradient is its own)."""
    if num_members is None:
        return losses.mean()
    return losses.reshape(-1, num_members, losses.shape[-1]).mean((0, 2))
