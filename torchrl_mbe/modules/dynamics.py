"""Dynamics modules: ``D(s, a)`` predicts the next observation, learned (:class:`DynamicsModel`) or exact (:class:`ExactDynamics`)."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import NestedKey, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import nn
from torchrl.data import ReplayBuffer, TensorSpec
from torchrl.modules import MLP

from torchrl_mbe.modules.actions import action_indices, discrete_action_spec, num_discrete_actions, one_hot_actions
from torchrl_mbe.modules.networks import forward_on_hot_entries, init_linear_layers, make_members_mlp
from torchrl_mbe.modules.normalization import Standardize
from torchrl_mbe.modules.observations import categorical_groups, flat_observation_size, hot_entries

__all__ = [
    "DynamicsModel",
    "ExactDynamics",
    "action_indices",
    "categorical_groups",
    "check_output",
    "hot_entries",
    "num_discrete_actions",
    "one_hot_actions",
]  # the action helpers live in .actions, the spec readers in .observations

OUTPUTS = ("delta", "categorical")


def check_output(output: str, normalize: bool) -> None:
    """Raises ``ValueError`` unless ``output`` is one of :data:`OUTPUTS` and, when categorical, ``normalize`` is off."""
    if output not in OUTPUTS:
        raise ValueError(f"output must be one of {OUTPUTS}, got {output!r}.")
    if output == "categorical" and normalize:
        raise ValueError(
            "output='categorical' predicts probabilities over the observation's entries in raw units; pass normalize=False."
        )


class ExactDynamics(TensorDictModuleBase):
    """Base of a task's true dynamics as a dynamics module (an oracle): nothing to learn, the planner's contract kept.

    Subclasses implement :meth:`step` on the observation and the integer action
    index; this class reads the keys and the action encoding.

    Args:
        action_spec (OneHot, Categorical or Composite): how ``action`` is encoded
            (a ``Composite``, such as a ``QValueActor``'s spec, through its ``action_key`` entry).

    Keyword Args:
        observation_key (NestedKey): defaults to ``"observation"``.
        action_key (NestedKey): defaults to ``"action"``.
        out_key (NestedKey): defaults to ``"predicted_observation"``.
    """

    def __init__(
        self,
        action_spec: TensorSpec,
        *,
        observation_key: NestedKey = "observation",
        action_key: NestedKey = "action",
        out_key: NestedKey = "predicted_observation",
    ) -> None:
        super().__init__()
        self.action_spec = discrete_action_spec(action_spec, action_key)
        self.in_keys = [observation_key, action_key]
        self.out_keys = [out_key]

    def step(self, observation: torch.Tensor, action_index: torch.Tensor) -> torch.Tensor:
        """The next observation after the action of index ``action_index`` from ``observation``."""
        raise NotImplementedError

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        observation_key, action_key = self.in_keys
        action_index = action_indices(tensordict.get(action_key), self.action_spec)
        tensordict.set(self.out_keys[0], self.step(tensordict.get(observation_key), action_index))
        return tensordict


class DynamicsModel(TensorDictModuleBase):
    """An MLP that predicts the next observation from an observation and a discrete action.

    As in mbrl-lib, the network predicts the standardized state *delta*
    ``s' - s`` from the standardized observation and the one-hot action, and the
    delta is added back to ``s``. The statistics are buffers (saved beside the
    weights in ``state_dict``), identity until fitted: by :meth:`fit_normalization`
    on data or a replay buffer, or else by :class:`~torchrl_mbe.DynamicsLoss` on the
    first batch it trains on (as TorchRL's ``ObservationNorm`` can init its
    statistics from data). Fit before training, since a refit changes what the
    network's outputs mean; :attr:`normalization_fitted` says whether they are, and
    travels with ``state_dict``.
    Defaults follow the paper's appendix: two hidden layers of 24 ReLU units with
    Glorot-uniform weights.

    Args:
        observation_size (int or TensorSpec): size of the (flat) observation
            vector, or a spec it is read from: the observation's own spec, or a
            ``Composite`` holding it under ``observation_key`` (``env.observation_spec``).
        action_spec (OneHot, Categorical or Composite): the env's action spec, or a
            ``Composite`` holding it under ``action_key`` (a ``QValueActor``'s ``spec``);
            it decides how ``action`` is encoded in the input tensordict.
        num_cells (sequence of int): hidden layer sizes. Defaults to ``(24, 24)``.

    Keyword Args:
        activation_class (type): hidden activation. Defaults to ``nn.ReLU``.
        observation_key (NestedKey): input observation. Defaults to ``"observation"``.
        action_key (NestedKey): input action. Defaults to ``"action"``.
        out_key (NestedKey): output. Defaults to ``"predicted_observation"``.
        num_members (int, optional): a population of ``M`` independent models
            (one TorchRL ``MultiAgentMLP``, statistics of shape ``(M, F)``) reading
            ``[*B, M, F]`` observations; ``None`` (the default) is one model.
        prior_scale (float): weight of a *randomized prior* (Osband et al., 2018): a
            second network of the same shape, random and frozen, whose output is
            added to the trained network's. Where the model has trained, the
            network has learned to cancel it; where it has not, predictions carry
            the prior's noise and land off the visited states, so a novelty
            planner scores untried (state, action) pairs as novel instead of
            as "stay where you are". ``0`` (the default) builds no prior.
        prior_num_cells (sequence of int, optional): the prior's hidden layer sizes;
            ``None`` (the default) is ``num_cells``. A narrow prior's outputs span few
            directions, less for the trained network to cancel on the pairs it has
            tried (on DeepSea-30 a 32-unit prior cut the model's error to the
            1,024-unit model's, though not how deep the planner got; docs/results.md,
            section 6). Its outputs are smaller too (Glorot initialization): raise
            ``prior_scale`` to keep their size.
        normalize (bool): standardize inputs and deltas (the default). ``False``
            keeps raw units (statistics stay the identity and :meth:`fit_normalization`
            does nothing), for one-hot observations such as DeepSea's grid, where a
            rarely visited cell's tiny spread would scale its entry up a hundredfold.
        output (str): ``"delta"`` (the default) predicts the state's change;
            ``"categorical"``, for one-hot observations (DeepSea's grid, with
            ``normalize=False``), predicts the next observation as a softmax over its
            entries and one class more for an observation of zeros (DeepSea's after its
            last row), trained by :class:`~torchrl_mbe.DynamicsLoss` with cross-entropy;
            an observation of several one-hot groups (a ``MultiOneHot`` spec, such as
            a ``MultiDiscrete``'s: :func:`categorical_groups`) gets one softmax per group.
            A delta's predictions lie in an affine span of ``num_cells[-1] + 1``
            directions, fewer than the distinct next cells a large grid needs; a
            softmax's peak can sit on any entry (docs/results.md, section 6). With a
            prior, a categorical network has as many outputs again: an *offset*,
            trained to cancel the prior where the model has data, added to the
            softmax; where it has none the prediction lands off every cell, as a
            delta model's does (a softmax alone puts an untried action's next cell
            on a visited one).
        hot_entries (int, optional): the number of ones of a one-hot observation
            (1 for DeepSea's cells, one per group of a ``MultiOneHot``), read in raw
            units (``normalize=False``): the first layers of the network and of its
            prior then add the weight columns of those entries and of the action
            instead of multiplying the whole vector, the same values to float
            rounding. An input that is not such a code (a prediction the planner
            rolls on with ``horizon > 1``), and a compiled call, take the whole product.
        device (torch.device, optional): where parameters and buffers live.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl.envs import GymEnv
        >>> from torchrl_mbe import DynamicsModel
        >>> env = GymEnv("MountainCar-v0")
        >>> dynamics = DynamicsModel(env.observation_spec, env.action_spec)  # 2 features, 3 one-hot actions
        >>> td = TensorDict({"observation": torch.zeros(5, 2), "action": env.action_spec.rand((5,))}, [5])
        >>> dynamics(td)["predicted_observation"].shape
        torch.Size([5, 2])
        >>> dynamics.normalization_fitted
        False
        >>> optimistic = DynamicsModel(env.observation_spec, env.action_spec, prior_scale=10.0)  # a frozen random prior
        >>> any(parameter.requires_grad for parameter in optimistic.prior.parameters())
        False
        >>> narrow = DynamicsModel(env.observation_spec, env.action_spec, prior_scale=25.0, prior_num_cells=[8])
        >>> narrow.prior[0].out_features, narrow.net[0].out_features
        (8, 24)
        >>> grid = DynamicsModel(9, env.action_spec, [16], output="categorical", normalize=False)  # a 3 x 3 one-hot grid
        >>> grid.predict(torch.eye(9)[:1], env.action_spec.rand((1,))).sum(-1) <= 1  # probabilities over the 9 cells (the rest on zeros)
        tensor([True])
        >>> from torchrl.data import MultiOneHot
        >>> codes = DynamicsModel(MultiOneHot([4, 3]), env.action_spec, [16], output="categorical", normalize=False)
        >>> prediction = codes.predict(torch.tensor([[0.0, 1, 0, 0, 1, 0, 0]]), env.action_spec.rand((1,)))
        >>> prediction[:, :4].sum(-1) <= 1, prediction[:, 4:].sum(-1) <= 1  # one softmax per group
        (tensor([True]), tensor([True]))
    """

    def __init__(
        self,
        observation_size: int | TensorSpec,
        action_spec: TensorSpec,
        num_cells: Sequence[int] = (24, 24),
        *,
        activation_class: type[nn.Module] = nn.ReLU,
        observation_key: NestedKey = "observation",
        action_key: NestedKey = "action",
        out_key: NestedKey = "predicted_observation",
        num_members: int | None = None,
        prior_scale: float = 0.0,
        prior_num_cells: Sequence[int] | None = None,
        normalize: bool = True,
        output: str = "delta",
        hot_entries: int | None = None,
        device: torch.device | str | None = None,
    ) -> None:
        super().__init__()
        check_output(output, normalize)
        if hot_entries is not None and normalize:
            raise ValueError("hot_entries reads raw one-hot codes: pass normalize=False with it.")
        self.hot_entries = hot_entries
        groups = categorical_groups(observation_size, observation_key)
        observation_size = flat_observation_size(observation_size, observation_key)
        prior_num_cells = list(num_cells if prior_num_cells is None else prior_num_cells)
        if observation_size < 1 or any(int(cells) < 1 for cells in [*num_cells, *prior_num_cells]):
            raise ValueError(
                f"observation_size, num_cells and prior_num_cells must be positive, got {observation_size}, {list(num_cells)} and {prior_num_cells}."
            )
        if prior_scale < 0:
            raise ValueError(f"prior_scale must be >= 0 (0: no prior), got {prior_scale}.")
        self.in_keys = [observation_key, action_key]
        self.out_keys = [out_key]
        self.action_spec = discrete_action_spec(action_spec, action_key)
        self.observation_size = observation_size
        self.groups = groups
        self.num_members = num_members
        in_features = observation_size + num_discrete_actions(self.action_spec)
        self.output = output
        self.prior_scale = prior_scale
        for name, layout in zip(("_padding", "_entry_index", "_group_of_entry"), _group_layout(groups)):
            # a categorical model's layout of its logits; a delta model has none
            self.register_buffer(name, layout.to(device) if output == "categorical" else None, persistent=False)
        self.net = self._make_net(in_features, list(num_cells), activation_class, device, self._net_outputs())
        self.prior = (
            self._make_net(in_features, prior_num_cells, activation_class, device, observation_size).requires_grad_(
                False
            )
            if prior_scale > 0
            else None
        )
        statistics_shape = observation_size if num_members is None else (num_members, observation_size)
        self.observation_norm = Standardize(statistics_shape, device=device)
        self.delta_norm = Standardize(statistics_shape, device=device)
        self.normalize = normalize
        self.normalization_fitted = not normalize  # raw units need no fit

    def _net_outputs(self) -> int:
        """A delta per feature; or a row of logits per group (:func:`_group_layout`), then an offset per feature when there is a prior to cancel."""
        if self.output == "delta":
            return self.observation_size
        return self._padding.numel() + (self.observation_size if self.prior_scale > 0 else 0)

    def _make_net(
        self, in_features: int, num_cells: list[int], activation_class: type[nn.Module], device, out_features: int
    ) -> nn.Module:
        """The MLP (Glorot-uniform weights, zero biases), or the members' ``MultiAgentMLP``."""
        if self.num_members is not None:
            return make_members_mlp(
                in_features, out_features, num_cells, self.num_members, activation_class=activation_class, device=device
            )
        mlp = MLP(
            in_features=in_features,
            out_features=out_features,
            num_cells=num_cells,
            activation_class=activation_class,
            device=device,
        )
        return init_linear_layers(mlp)

    @property
    def delta_scale(self) -> torch.Tensor:
        """Typical size of each dimension's change; :class:`DynamicsLoss` measures errors in these units."""
        return self.delta_norm.scale

    def _inputs(self, observation: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        normalized = self.observation_norm(observation)
        return torch.cat([normalized, one_hot_actions(action, self.action_spec).to(normalized)], -1)

    def _outputs(self, observation: torch.Tensor, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The network's and the prior's outputs (``None`` without a prior), on the hot entries of a one-hot ``observation`` where it is one."""
        hot = self._hot_inputs(observation, action)
        if hot is None:
            inputs = self._inputs(observation, action)
            return self.net(inputs), None if self.prior is None else self.prior(inputs)
        return forward_on_hot_entries(self.net, hot), None if self.prior is None else forward_on_hot_entries(
            self.prior, hot
        )

    def _hot_inputs(self, observation: torch.Tensor, action: torch.Tensor) -> torch.Tensor | None:
        """The indices ``[*B, hot_entries + 1]`` of the input's ones (the observation's, then the action's), or ``None``.

        ``None`` without ``hot_entries``, for an observation that is not such a code, and
        compiled (``torch.compile(fullgraph=True)``, as a Collector's ``compile_policy``),
        where no branch may depend on the data: the whole product then.
        """
        if self.hot_entries is None or torch.compiler.is_compiling():
            return None
        is_code = ((observation == 0) | (observation == 1)).all() and (observation.sum(-1) == self.hot_entries).all()
        if not is_code:
            return None
        action_index = action_indices(action, self.action_spec).expand(observation.shape[:-1])
        return torch.cat(
            [observation.topk(self.hot_entries, dim=-1).indices, self.observation_size + action_index.unsqueeze(-1)], -1
        )

    def categorical_parts(
        self, observation: torch.Tensor, action: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """A categorical model's logits (one per feature, the last for zeros) and its offset (the trained offset plus the prior; ``None`` without a prior)."""
        output, prior = self._outputs(observation, action)
        if prior is None:
            return output, None
        logits, offset = output.split([self._padding.numel(), self.observation_size], -1)
        return logits, offset + self.prior_scale * prior

    def grouped_logits(self, logits: torch.Tensor) -> torch.Tensor:
        """A categorical model's logits as ``[*, W, G]``: a column per group, its entries, ``-inf`` padding, and its class of zeros last."""
        return logits.unflatten(-1, self._padding.shape) + self._padding

    def categorical_log_likelihood(self, logits: torch.Tensor, observation: torch.Tensor) -> torch.Tensor:
        """The log-probability, ``[*, 1]``, that a categorical model's logits give a (one-hot) ``observation``: its groups' classes' summed.

        A group of zeros (DeepSea's observation after its last row) is its class of zeros.
        """
        log_probabilities = _class_softmax(self.grouped_logits(logits), torch.log_softmax).flatten(-2)
        entries = log_probabilities.index_select(-1, self._entry_index)
        zeros = 1 - observation.new_zeros((*observation.shape[:-1], len(self.groups))).index_add(
            -1, self._group_of_entry, observation
        )
        zeros_log_probabilities = log_probabilities[..., -len(self.groups) :]  # the last row: the classes of zeros
        return (observation * entries).sum(-1, keepdim=True) + (zeros * zeros_log_probabilities).sum(-1, keepdim=True)

    def categorical_prediction(self, logits: torch.Tensor, offset: torch.Tensor | None) -> torch.Tensor:
        """The next observation a categorical model's parts predict: each feature's probability within its group (the classes of zeros add nothing), plus the offset."""
        probabilities = _class_softmax(self.grouped_logits(logits), torch.softmax)
        probabilities = probabilities.flatten(-2).index_select(-1, self._entry_index)
        return probabilities if offset is None else probabilities + offset

    def predict(self, observation: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """Predicted next observation for tensors (actions encoded as the spec encodes them)."""
        if self.output == "categorical":
            return self.categorical_prediction(*self.categorical_parts(observation, action))
        output, prior = self._outputs(observation, action)
        if prior is not None:
            output = output + self.prior_scale * prior
        return observation + self.delta_norm.loc + self.delta_norm.scale * output

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        observation_key, action_key = self.in_keys
        prediction = self.predict(tensordict.get(observation_key), tensordict.get(action_key))
        tensordict.set(self.out_keys[0], prediction)
        return tensordict

    @torch.no_grad()
    def fit_normalization(
        self,
        data: TensorDictBase | ReplayBuffer,
        *,
        next_observation_key: NestedKey = ("next", "observation"),
        min_scale: float = 1e-6,
    ) -> None:
        """Refits the input and delta statistics from transitions.

        Args:
            data (TensorDictBase or replay buffer): transitions holding the
                observation and the next observation; a replay buffer (TorchRL's, or
                a :class:`~torchrl_mbe.app.replay.PopulationReplayBuffer`) is read whole.

        Keyword Args:
            next_observation_key (NestedKey): where the next observation is.
            min_scale (float): dimensions whose standard deviation is at most this are left unscaled.
        """
        if not self.normalize:
            return
        if not isinstance(data, TensorDictBase):
            data = data[: len(data)]
        observation = data.get(self.in_keys[0])
        self.observation_norm.fit(observation, min_scale)
        self.delta_norm.fit(data.get(next_observation_key) - observation, min_scale)
        self.normalization_fitted = True

    def get_extra_state(self) -> dict:
        # A Python flag, not a buffer: reading it costs no device sync, and torch.compile guards on it
        # instead of breaking the graph on a data-dependent branch.
        return {"normalization_fitted": self.normalization_fitted}

    def set_extra_state(self, state: dict) -> None:
        self.normalization_fitted = bool(state["normalization_fitted"])

    def _load_from_state_dict(self, state_dict: dict, prefix: str, *args, **kwargs) -> None:
        # A state_dict saved before the flag existed: keep its statistics as they are (never auto-refit a trained model).
        state_dict.setdefault(prefix + "_extra_state", {"normalization_fitted": True})
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)


def _class_softmax(grouped: torch.Tensor, function=torch.softmax) -> torch.Tensor:
    """``torch.softmax`` (or ``torch.log_softmax``) over the classes of ``[*, W, G]`` grouped logits.

    Over the class dimension, before the groups' (CPU's softmax is slow along a short last
    dimension); one group as one flat row, the order of DeepSea's runs.
    """
    if grouped.shape[-1] == 1:
        return function(grouped.squeeze(-1), -1).unsqueeze(-1)
    return function(grouped, -2)


def _group_layout(groups: Sequence[int]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """A categorical model's logits as ``W`` rows (the largest group plus one) of a column per group: what each adds, where each feature sits, and its group.

    Column ``g`` holds group ``g``'s entries, then padding up to row ``W - 1``, then its
    class of zeros. ``padding`` (``[W, G]``) is ``-inf`` on the padding and ``0`` elsewhere
    (so a softmax never gives padding any probability); ``entry_index[i]`` is feature
    ``i``'s place in the flattened ``[W, G]`` logits, ``group_of_entry[i]`` its group. One
    group (DeepSea's cells) is one column, unpadded, in the order of the features.
    """
    width = max(groups) + 1
    padding = torch.zeros(width, len(groups))
    entry_index = []
    for column, size in enumerate(groups):
        padding[size:-1, column] = -torch.inf
        entry_index.extend(range(column, size * len(groups), len(groups)))
    group_of_entry = torch.repeat_interleave(torch.arange(len(groups)), torch.tensor(groups))
    return padding, torch.tensor(entry_index, dtype=torch.long), group_of_entry
