"""Learned dynamics: ``D(s, a)`` predicts the next observation."""
from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import NestedKey, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import nn
from torchrl.data import Categorical, OneHot, ReplayBuffer, TensorSpec
from torchrl.modules import MLP

from torchrl_mbe.modules.networks import init_linear_layers
from torchrl_mbe.modules.normalization import Standardize

__all__ = ["DynamicsModel", "action_indices", "num_discrete_actions", "one_hot_actions"]


def num_discrete_actions(action_spec: TensorSpec) -> int:
    """Number of actions of a ``OneHot`` or ``Categorical`` spec; a clear error otherwise."""
    if not isinstance(action_spec, (OneHot, Categorical)):
        raise TypeError(
            "Model-based exploration needs a discrete action spec (OneHot or Categorical), "
            f"got {type(action_spec).__name__}."
        )
    return int(action_spec.space.n)


def action_indices(action: torch.Tensor, action_spec: TensorSpec) -> torch.Tensor:
    """Integer action indices of actions encoded as ``action_spec`` encodes them."""
    return action.long().argmax(-1) if isinstance(action_spec, OneHot) else action.long()


def one_hot_actions(action: torch.Tensor, action_spec: TensorSpec) -> torch.Tensor:
    """Float one-hot encoding of actions encoded as ``action_spec`` encodes them."""
    if isinstance(action_spec, OneHot):
        return action.float()
    return nn.functional.one_hot(action.long(), num_discrete_actions(action_spec)).float()


class DynamicsModel(TensorDictModuleBase):
    """An MLP that predicts the next observation from an observation and a discrete action.

    As in mbrl-lib, the network predicts the standardized state *delta*
    ``s' - s`` from the standardized observation and the one-hot action, and the
    delta is added back to ``s``. The statistics are buffers (saved beside the
    weights in ``state_dict``), identity until :meth:`fit_normalization` refits
    them from data or a replay buffer; refit before training, since a refit
    changes what the network's outputs mean.
    Defaults follow the paper's appendix: two hidden layers of 24 ReLU units with
    Glorot-uniform weights.

    Args:
        observation_size (int): size of the (flat) observation vector.
        action_spec (OneHot or Categorical): the env's action spec; it decides
            how ``action`` is encoded in the input tensordict.
        num_cells (sequence of int): hidden layer sizes. Defaults to ``(24, 24)``.

    Keyword Args:
        activation_class (type): hidden activation. Defaults to ``nn.ReLU``.
        observation_key (NestedKey): input observation. Defaults to ``"observation"``.
        action_key (NestedKey): input action. Defaults to ``"action"``.
        out_key (NestedKey): output. Defaults to ``"predicted_observation"``.
        device (torch.device, optional): where parameters and buffers live.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl.data import OneHot
        >>> from torchrl_mbe import DynamicsModel
        >>> dynamics = DynamicsModel(observation_size=2, action_spec=OneHot(3))
        >>> td = TensorDict({"observation": torch.zeros(5, 2), "action": OneHot(3).rand((5,))}, [5])
        >>> dynamics(td)["predicted_observation"].shape
        torch.Size([5, 2])
    """

    def __init__(
        self,
        observation_size: int,
        action_spec: TensorSpec,
        num_cells: Sequence[int] = (24, 24),
        *,
        activation_class: type[nn.Module] = nn.ReLU,
        observation_key: NestedKey = "observation",
        action_key: NestedKey = "action",
        out_key: NestedKey = "predicted_observation",
        device: torch.device | str | None = None,
    ) -> None:
        super().__init__()
        if int(observation_size) < 1 or any(int(cells) < 1 for cells in num_cells):
            raise ValueError(
                f"observation_size and num_cells must be positive, got {observation_size} and {list(num_cells)}."
            )
        self.in_keys = [observation_key, action_key]
        self.out_keys = [out_key]
        self.action_spec = action_spec
        num_actions = num_discrete_actions(action_spec)
        self.net = init_linear_layers(
            MLP(
                in_features=observation_size + num_actions,
                out_features=observation_size,
                num_cells=list(num_cells),
                activation_class=activation_class,
                device=device,
            )
        )
        self.observation_norm = Standardize(observation_size, device=device)
        self.delta_norm = Standardize(observation_size, device=device)

    @property
    def delta_scale(self) -> torch.Tensor:
        """Typical size of each dimension's change; :class:`DynamicsLoss` measures errors in these units."""
        return self.delta_norm.scale

    def predict(self, observation: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """Predicted next observation for tensors (actions encoded as the spec encodes them)."""
        normalized = self.observation_norm(observation)
        inputs = torch.cat([normalized, one_hot_actions(action, self.action_spec).to(normalized)], -1)
        return observation + self.delta_norm.loc + self.delta_norm.scale * self.net(inputs)

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
            data (TensorDictBase or ReplayBuffer): transitions holding the
                observation and the next observation; a replay buffer is read whole.

        Keyword Args:
            next_observation_key (NestedKey): where the next observation is.
            min_scale (float): dimensions whose standard deviation is at most this are left unscaled.
        """
        if isinstance(data, ReplayBuffer):
            data = data[: len(data)]
        observation = data.get(self.in_keys[0])
        self.observation_norm.fit(observation, min_scale)
        self.delta_norm.fit(data.get(next_observation_key) - observation, min_scale)
