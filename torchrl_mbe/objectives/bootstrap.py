"""``BootstrapDQNLoss``: TorchRL's ``DQNLoss`` for every head of a Bootstrapped DQN ensemble, each on its own bootstrap mask."""

from __future__ import annotations

from tensordict import NestedKey, TensorDict, TensorDictBase
from torchrl.modules import QValueActor

from torchrl_mbe.modules.bootstrap import BootstrappedQValueActor
from torchrl_mbe.objectives.population import PopulationDQNLoss

__all__ = ["BootstrapDQNLoss"]


class BootstrapDQNLoss(PopulationDQNLoss):
    """Each head's DQN loss on a batch of transitions ``[*B]``, weighted by its bootstrap mask, summed over heads.

    The batch is read by every head (as ``[*B, K]``: each head its own view of the
    same transitions), so each head's targets come from its own target network (double
    DQN and n-step targets as ``DQNLoss`` computes them) and its loss is
    ``mean_b(mask[b, k] * loss[b, k])``; ``"member_loss"`` holds the ``K`` head losses,
    whose gradients touch their own head only (clip them per head with
    :func:`~torchrl_mbe.app.optim.clip_grad_norm_per_member_`). ``"td_error"`` is written
    into the input batch as the mean over heads, ``[*B, 1]`` (for prioritized replay).
    A population's ensembles (``M`` of them) read a ``[*B, M]`` batch as ``[*B, M, K]``;
    ``"member_loss"`` is then ``[M * K]``, member ``m``'s heads at ``m * K`` on.

    With ``K = 1``, a mask of ones and ``prior_scale = 0`` it takes the steps
    ``DQNLoss`` takes on the same network.

    Args:
        actor (BootstrappedQValueActor): the ensemble; its :attr:`network` is trained, as a ``QValueActor`` over
            a ``[*B, K]`` batch (each head reading its own copy of the transition).

    Keyword Args:
        mask_key (NestedKey): the ``[*B, K]`` bootstrap mask. Defaults to ``("next", "bootstrap_mask")``,
            where :class:`~torchrl_mbe.envs.transforms.BootstrapHeads` writes it.
        **kwargs: ``DQNLoss``'s keyword arguments (``delay_value``, ``double_dqn``, ``loss_function``, ``action_space``).

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl.data import OneHot
        >>> from torchrl_mbe.modules.bootstrap import BootstrappedQValueActor, EnsembleQNetwork
        >>> from torchrl_mbe.objectives.bootstrap import BootstrapDQNLoss
        >>> spec = OneHot(3)
        >>> actor = BootstrappedQValueActor(EnsembleQNetwork(2, 3, [16], num_heads=4, prior_scale=5.0), spec)
        >>> loss = BootstrapDQNLoss(actor, delay_value=True, double_dqn=True, action_space=spec)
        >>> flags = torch.zeros(8, 1, dtype=torch.bool)
        >>> mask = torch.ones(8, 4, dtype=torch.bool)
        >>> batch = TensorDict(observation=torch.randn(8, 2), action=spec.rand((8,)),
        ...     next=TensorDict(observation=torch.randn(8, 2), reward=torch.ones(8, 1), done=flags, terminated=flags,
        ...     bootstrap_mask=mask), batch_size=[8])
        >>> out = loss(batch)
        >>> out["member_loss"].shape, batch["td_error"].shape
        (torch.Size([4]), torch.Size([8, 1]))
    """

    def __init__(
        self, actor: BootstrappedQValueActor, *, mask_key: NestedKey = ("next", "bootstrap_mask"), **kwargs
    ) -> None:
        member_dims = 1 if actor.network.num_members is None else 2  # [K] or [M, K]
        super().__init__(
            QValueActor(actor.network, spec=actor.spec, in_keys=["observation"]),
            mask_key=mask_key,
            member_dims=member_dims,
            **kwargs,
        )
        self.num_heads = actor.network.num_heads

    def forward(self, tensordict: TensorDictBase) -> TensorDict:
        mask = tensordict.get(self.mask_key)
        heads = tensordict.exclude(self.mask_key).unsqueeze(-1).expand(*tensordict.batch_size, self.num_heads)
        heads.set(self.mask_key, mask)
        losses = super().forward(heads)
        tensordict.set("td_error", heads.get("td_error").mean(-2))
        return losses
