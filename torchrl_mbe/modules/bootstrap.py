"""Bootstrapped DQN with randomized prior functions (Osband et al. 2016; Osband, Aslanides and Cassirer 2018).

An ensemble of ``K`` Q-networks (heads), each a trainable network plus a fixed random
prior network scaled by ``prior_scale`` (``Q_k = f_k + beta p_k``), stacked as one
:class:`~torchrl_mbe.modules.networks.MembersMLP` (one batched product for all heads). The actor acts with one head per
episode (the index an env transform, :class:`~torchrl_mbe.envs.transforms.BootstrapHeads`,
draws at each reset and carries in the tensordict) and greedily by the heads' mean.
:class:`~torchrl_mbe.objectives.bootstrap.BootstrapDQNLoss` trains each head on its own
bootstrap mask, with its own target network.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule, TensorDictModuleBase, TensorDictSequential
from torch import nn
from torchrl.data import TensorSpec
from torchrl.envs.utils import ExplorationType, exploration_type
from torchrl.modules import QValueModule

from torchrl_mbe.modules.networks import forward_on_hot_entries, make_members_mlp

__all__ = ["BootstrappedQValueActor", "EnsembleQNetwork", "HeadSelector"]


class EnsembleQNetwork(nn.Module):
    """``K`` Q-networks with randomized priors: ``[*B, K, F]`` observations (one per head) to ``[*B, K, A]`` values.

    Head ``k`` computes ``f_k(x_k) + prior_scale * p_k(x_k)``: ``f`` and ``p`` are
    :func:`~torchrl_mbe.modules.networks.make_members_mlp`'s (ReLU hidden layers
    ``num_cells``, Glorot-uniform weights), ``p`` frozen at its initialization (no
    gradient, never in an optimizer's steps).

    With ``hot_entries`` the observations are one-hot codes with exactly that many ones
    (a ``OneHot`` spec's 1, a ``MultiOneHot``'s number of variables, read raw: no
    ``input_norm``): each head's first layer then adds the weight columns of the hot
    entries instead of multiplying by the whole vector. The values are those of the
    product, at a fraction of its work when ``F`` is large (DeepSea's ``N * N`` cells).

    A population of ``M`` ensembles (``num_members``) maps ``[*B, M, K, F]`` to
    ``[*B, M, K, A]``: its ``M * K`` heads are stacked as one ``MembersMLP``
    (member ``m``'s heads are ``m * K`` to ``m * K + K - 1``), and ``input_norm`` is
    the members' ``(M, F)`` statistics.

    Args:
        observation_size (int): features ``F``.
        num_actions (int): discrete actions ``A``.
        num_cells (sequence of int): hidden layer widths of each head and of its prior.
        num_heads (int): the ensemble's size ``K``.
        prior_scale (float): ``beta``; ``0`` gives Bootstrapped DQN without priors.

    Keyword Args:
        input_norm (nn.Module, optional): applied to the observations first
            (a :class:`~torchrl_mbe.modules.Standardize` of shape ``(F,)``, ``(M, F)`` with ``num_members``).
        num_members (int, optional): a population's ``M`` ensembles, each its own ``K`` heads.
        hot_entries (int, optional): the number of ones in every observation, when it is one-hot codes.
        device (torch.device or str): where the parameters live. Defaults to ``"cpu"``.

    Examples:
        >>> import torch
        >>> from torchrl_mbe.modules.bootstrap import EnsembleQNetwork
        >>> network = EnsembleQNetwork(2, 3, [16], num_heads=5, prior_scale=3.0)
        >>> network(torch.zeros(8, 5, 2)).shape
        torch.Size([8, 5, 3])
        >>> sum(p.numel() for p in network.parameters() if p.requires_grad) == sum(p.numel() for p in network.prior.parameters())
        True
        >>> cells = torch.nn.functional.one_hot(torch.tensor([[7, 7, 7, 7, 7]]), 100).float()  # one cell, every head
        >>> dense, sparse = EnsembleQNetwork(100, 3, [16], 5, 3.0), EnsembleQNetwork(100, 3, [16], 5, 3.0, hot_entries=1)
        >>> _ = sparse.load_state_dict(dense.state_dict())
        >>> torch.allclose(dense(cells), sparse(cells))
        True
        >>> population = EnsembleQNetwork(2, 3, [16], num_heads=5, prior_scale=3.0, num_members=4)
        >>> population(torch.zeros(8, 4, 5, 2)).shape, population.trainable.params["0", "weight"].shape
        (torch.Size([8, 4, 5, 3]), torch.Size([20, 16, 2]))
    """

    def __init__(
        self,
        observation_size: int,
        num_actions: int,
        num_cells: Sequence[int],
        num_heads: int,
        prior_scale: float,
        *,
        input_norm: nn.Module | None = None,
        num_members: int | None = None,
        hot_entries: int | None = None,
        device: torch.device | str = "cpu",
    ) -> None:
        super().__init__()
        if hot_entries is not None and input_norm is not None:
            raise ValueError("hot_entries reads raw one-hot codes: pass no input_norm with it.")
        self.num_heads, self.prior_scale, self.num_members = num_heads, prior_scale, num_members
        self.hot_entries = hot_entries
        self.input_norm = input_norm if input_norm is not None else nn.Identity()
        stacked = num_heads * (num_members or 1)
        self.trainable = make_members_mlp(observation_size, num_actions, num_cells, stacked, device=device)
        self.prior = make_members_mlp(observation_size, num_actions, num_cells, stacked, device=device)
        self.prior.requires_grad_(False)

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        if self.num_members is None:
            return self._heads(self.input_norm(observation))
        # each member's statistics (M, F) read [*B, K, M, F]; the M * K heads are one dimension
        observation = self.input_norm(observation.transpose(-3, -2)).transpose(-3, -2)
        return self._heads(observation).unflatten(-2, (self.num_members, self.num_heads))

    def _heads(self, observation: torch.Tensor) -> torch.Tensor:
        """``[*B, (M,) K, F]`` to ``[*B, H, A]``: each of the ``H = (M *) K`` stacked heads plus its scaled prior."""
        if self.hot_entries is None:
            observation = self._stacked(observation)
            return self.trainable(observation) + self.prior_scale * self.prior(observation)
        hot = self._stacked(_hot_entries(observation, self.hot_entries))  # found before an expanded view is copied
        return forward_on_hot_entries(self.trainable, hot) + self.prior_scale * forward_on_hot_entries(self.prior, hot)

    def _stacked(self, per_head: torch.Tensor) -> torch.Tensor:
        """A population's ``[*B, M, K, ...]`` as its stacked heads' ``[*B, M * K, ...]``; one ensemble's as it is."""
        return per_head.flatten(-3, -2) if self.num_members is not None else per_head

    def member_state_dict(self, member: int) -> dict[str, torch.Tensor]:
        """Member ``member``'s ensemble of a population's (``num_members``), keyed as one ensemble's ``state_dict``.

        Its ``K`` heads and priors are the ``[m * K, m * K + K)`` slice of the stacked
        parameters, its input statistics the ``[m]`` slice of the members' ``(M, F)``.
        """
        heads = slice(member * self.num_heads, (member + 1) * self.num_heads)
        state = {f"input_norm.{key}": value[member] for key, value in self.input_norm.state_dict().items()}
        for name in ("trainable", "prior"):
            state |= {f"{name}.{key}": value[heads] for key, value in getattr(self, name).state_dict().items()}
        return {key: value.clone() for key, value in state.items() if not value.is_meta}


def _hot_entries(observation: torch.Tensor, count: int) -> torch.Tensor:
    """The indices ``[*B, H, count]`` of the ones in one-hot codes ``[*B, H, F]``, found once where every head reads the same codes."""
    if observation.stride(-2) == 0:  # one observation expanded to every head: its rows are one row
        return observation[..., :1, :].topk(count, dim=-1).indices.expand(*observation.shape[:-1], count)
    return observation.topk(count, dim=-1).indices


class _AllHeads(nn.Module):
    """One observation ``[*B, F]`` given to every head: ``[*B, K, A]`` (a population's ``[*B, M, F]``: ``[*B, M, K, A]``)."""

    def __init__(self, network: EnsembleQNetwork) -> None:
        super().__init__()
        self.network = network

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        heads = observation.unsqueeze(-2).expand(*observation.shape[:-1], self.network.num_heads, observation.shape[-1])
        return self.network(heads)


class HeadSelector(TensorDictModuleBase):
    """The values an ensemble acts on: the episode's head while exploring, the heads' mean otherwise.

    Under ``ExplorationType.RANDOM`` (a collector's default) or no exploration type,
    and with ``head_key`` in the tensordict, it takes head ``head_key``'s values of
    ``[*B, K, A]``; under ``DETERMINISTIC`` (evaluation), or without a head, the mean
    over heads: the greedy policy of the ensemble's mean Q-value, smoother than a
    vote (which ties with an even number of heads) and the estimate the heads are trained towards.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl.envs.utils import ExplorationType, set_exploration_type
        >>> from torchrl_mbe.modules.bootstrap import HeadSelector
        >>> values = torch.tensor([[[1.0, 0.0], [0.0, 3.0]]])  # one env, two heads, two actions
        >>> td = TensorDict(action_value_heads=values, head=torch.tensor([0]), batch_size=[1])
        >>> HeadSelector()(td)["action_value"].tolist()
        [[1.0, 0.0]]
        >>> with set_exploration_type(ExplorationType.DETERMINISTIC):
        ...     HeadSelector()(td)["action_value"].tolist()
        [[0.5, 1.5]]
    """

    def __init__(
        self, heads_key: str = "action_value_heads", head_key: str = "head", out_key: str = "action_value"
    ) -> None:
        super().__init__()
        self.in_keys, self.out_keys = [heads_key, head_key], [out_key]
        self.heads_key, self.head_key, self.out_key = heads_key, head_key, out_key

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        heads = tensordict.get(self.heads_key)  # [*B, K, A]
        head = tensordict.get(self.head_key, None)
        if head is None or exploration_type() not in (ExplorationType.RANDOM, None):
            return tensordict.set(self.out_key, heads.mean(-2))
        index = head.reshape(*head.shape, 1, 1).expand(*head.shape, 1, heads.shape[-1])
        return tensordict.set(self.out_key, heads.gather(-2, index).squeeze(-2))


class BootstrappedQValueActor(TensorDictSequential):
    """An ensemble's Q-value actor: every head's values, the acting head's (or the mean's), then TorchRL's ``QValueModule``.

    It reads ``"observation"`` (and ``"head"``, written by
    :class:`~torchrl_mbe.envs.transforms.BootstrapHeads`) and writes
    ``"action_value_heads"`` ``[*B, K, A]``, ``"action_value"``, ``"action"`` and
    ``"chosen_action_value"`` as TorchRL's ``QValueActor`` does, and declares its
    ``spec`` as one does. :attr:`network` is what the loss trains; the weights are
    held once, so ``state_dict`` has each of them once. A population's ensembles
    (``EnsembleQNetwork(..., num_members=M)``) read ``[*B, M]`` batches, each env's head
    one of its member's ``K``.

    Args:
        network (EnsembleQNetwork): the heads.
        spec (TensorSpec): the (one-hot) action spec, or a ``Composite`` with an ``"action"`` entry.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl.data import OneHot
        >>> from torchrl_mbe.modules.bootstrap import BootstrappedQValueActor, EnsembleQNetwork
        >>> actor = BootstrappedQValueActor(EnsembleQNetwork(2, 3, [16], num_heads=4, prior_scale=5.0), OneHot(3))
        >>> step = actor(TensorDict(observation=torch.zeros(6, 2), head=torch.zeros(6, dtype=torch.long), batch_size=[6]))
        >>> step["action_value_heads"].shape, step["action"].shape
        (torch.Size([6, 4, 3]), torch.Size([6, 3]))
    """

    def __init__(self, network: EnsembleQNetwork, spec: TensorSpec) -> None:
        super().__init__(
            TensorDictModule(_AllHeads(network), in_keys=["observation"], out_keys=["action_value_heads"]),
            HeadSelector(),
            QValueModule(spec=spec),
        )
        self.spec = self.module[-1].spec  # QValueModule's: the action, its values (what a QValueActor declares)

    @property
    def network(self) -> EnsembleQNetwork:
        """The heads (held by the first module, which gives every head the observation)."""
        return self.module[0].module.network

    def member_state_dict(self, member: int) -> dict[str, torch.Tensor]:
        """A population's member ``member``: its ensemble, keyed as one ensemble's actor (``best_policy.pt`` loads into one)."""
        prefix = next(name for name, module in self.named_modules() if module is self.network)
        return {f"{prefix}.{key}": value for key, value in self.network.member_state_dict(member).items()}
