"""A population's losses: TorchRL's ``DQNLoss`` and ``RNDLoss`` with one loss per member, so that a member's gradient is its own.

The member dimension ``M`` is the last batch dimension, right before the features:
observations are ``[*B, M, F]``, action values ``[*B, M, A]``, an env batch is
``[num_envs, M]``, the replay storage ``[capacity, M]`` and a training batch
``[batch_size, M]`` (docs/architecture.md, "Where the member dimension lives").
"""

from __future__ import annotations

from typing import ClassVar

import torch
from tensordict import NestedKey, TensorDict, TensorDictBase
from torch import nn
from torchrl.modules import QValueActor
from torchrl.objectives import DQNLoss, RNDLoss

__all__ = ["PopulationDQNLoss", "PopulationRNDLoss"]


class PopulationDQNLoss(DQNLoss):
    """TorchRL's ``DQNLoss`` on a population batch ``[*B, M]``, with one mean per member, summed over members.

    ``DQNLoss`` runs unchanged on such a batch (actions one-hot ``[*B, M, A]``, rewards
    and done flags ``[*B, M, 1]``; its value network then reads ``[*B, M, F]``), and
    with ``reduction="mean"`` it would average over all ``B * M`` samples, giving each
    member ``1 / M`` of its own gradient. Here the per-sample losses
    (``reduction="none"``) are averaged over ``B`` for each member and the ``M`` means
    are summed: member ``m``'s gradient is exactly the gradient of its own
    single-agent ``DQNLoss`` (mean over its ``B`` samples), whatever ``M`` is.

    Args:
        value_network (QValueActor): e.g. :func:`make_population_q_actor`'s.

    Keyword Args:
        mask_key (NestedKey, optional): a ``[*B, M]`` entry of the batch that weighs each
            sample's loss (a bootstrap mask: 0 leaves the sample out of that member's
            mean, which stays over all ``B``, as bsuite's ``boot_dqn`` takes it).
        member_dims (int): how many of the batch's last dimensions index members. Defaults to ``1``;
            ``2`` for a population of ensembles (``[*B, M, K]``: its ``M * K`` heads are the members).
        **kwargs: ``DQNLoss``'s keyword arguments (``delay_value``, ``double_dqn``,
            ``loss_function``, ``action_space``, ...), except ``reduction``.

    Returns (from ``forward``):
        a TensorDict with ``"loss"`` (the scalar to back-propagate) and
        ``"member_loss"`` (``[M]``: each member's own loss, whose sum is ``"loss"``).
        ``"td_error"`` is written into the input batch as ``DQNLoss`` does, ``[*B, M, 1]``.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl.data import OneHot
        >>> from torchrl_mbe.modules.networks import make_population_q_actor
        >>> from torchrl_mbe.objectives.population import PopulationDQNLoss
        >>> spec = OneHot(3)
        >>> actor = make_population_q_actor(2, spec, [16], num_members=4)
        >>> loss = PopulationDQNLoss(actor, delay_value=True, double_dqn=True, loss_function="smooth_l1", action_space=spec)
        >>> flags = torch.zeros(8, 4, 1, dtype=torch.bool)
        >>> batch = TensorDict(
        ...     observation=torch.randn(8, 4, 2),
        ...     action=spec.rand((8, 4)),
        ...     next=TensorDict(observation=torch.randn(8, 4, 2), reward=torch.ones(8, 4, 1), done=flags, terminated=flags),
        ...     batch_size=[8, 4],
        ... )
        >>> out = loss(batch)
        >>> out["loss"].shape, out["member_loss"].shape, batch["td_error"].shape
        (torch.Size([]), torch.Size([4]), torch.Size([8, 4, 1]))
    """

    out_keys: ClassVar[list[str]] = ["loss", "member_loss"]

    def __init__(
        self, value_network: QValueActor, *, mask_key: NestedKey | None = None, member_dims: int = 1, **kwargs
    ) -> None:
        if kwargs.pop("reduction", "none") != "none":
            raise ValueError("PopulationDQNLoss reduces per member itself; do not pass reduction.")
        super().__init__(value_network, reduction="none", **kwargs)
        self.mask_key, self.member_dims = mask_key, member_dims

    def forward(self, tensordict: TensorDictBase) -> TensorDict:
        per_sample = super().forward(tensordict)["loss"]  # [*B, M]
        if self.mask_key is not None:
            per_sample = per_sample * tensordict.get(self.mask_key).to(per_sample.dtype)  # a bool mask too
        per_sample = per_sample.flatten(per_sample.ndim - self.member_dims)  # one member dimension
        member_loss = per_sample.reshape(-1, per_sample.shape[-1]).mean(0)
        return TensorDict(loss=member_loss.sum(), member_loss=member_loss)


class PopulationRNDLoss(RNDLoss):
    """TorchRL's ``RNDLoss`` on a population batch ``[*B, M]``: each member's mean over its own kept samples, summed.

    ``RNDLoss`` keeps a random ``update_fraction`` of the samples and averages the
    loss over those kept in the whole batch, which on ``B * M`` samples would give
    each member about ``1 / M`` of its gradient. Here the kept samples are drawn
    as ``RNDLoss`` draws them, and each member's loss is the mean over its own kept
    samples, as a single ``RNDLoss`` on its ``B`` samples computes it.

    Args:
        predictor_network, target_network (nn.Module): ``[*B, M, F]`` to ``[*B, M, E]``.

    Keyword Args:
        obs_rms (RunningMeanStd, optional): :class:`PopulationRNDTransform`'s ``(M, F)`` statistics.
        update_fraction (float): the fraction of each member's samples kept. Defaults to ``0.25``.
        **kwargs: ``RNDLoss``'s ``obs_clip``.

    Returns (from ``forward``):
        a TensorDict with ``"loss_predictor"`` (the scalar sum) and ``"member_loss"`` (``[M]``).

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl_mbe.modules.networks import make_members_mlp
        >>> from torchrl_mbe.objectives.population import PopulationRNDLoss
        >>> loss = PopulationRNDLoss(*(make_members_mlp(2, 8, [16], num_members=3, glorot=False) for _ in range(2)))
        >>> out = loss(TensorDict(next=TensorDict(observation=torch.randn(64, 3, 2), batch_size=[64, 3]), batch_size=[64, 3]))
        >>> out["member_loss"].shape, bool(out["loss_predictor"] == out["member_loss"].sum())
        (torch.Size([3]), True)
    """

    out_keys: ClassVar[list[str]] = ["loss_predictor", "member_loss"]

    def __init__(
        self, predictor_network: nn.Module, target_network: nn.Module, *, update_fraction: float = 0.25, **kwargs
    ) -> None:
        super().__init__(predictor_network, target_network, reduction="none", update_fraction=1.0, **kwargs)
        if not 0.0 < update_fraction <= 1.0:
            raise ValueError(f"update_fraction must be in (0, 1], got {update_fraction}.")
        self.member_update_fraction = update_fraction

    def forward(self, tensordict: TensorDictBase) -> TensorDict:
        per_sample = super().forward(tensordict)["loss_predictor"]  # [*B, M], every sample
        per_sample = per_sample.reshape(-1, per_sample.shape[-1])
        kept = torch.rand(per_sample.shape, device=per_sample.device) < self.member_update_fraction
        member_loss = torch.where(kept, per_sample, torch.zeros_like(per_sample)).sum(0) / kept.sum(0).clamp_min(1)
        return TensorDict(loss_predictor=member_loss.sum(), member_loss=member_loss)
