"""Small network helpers shared by the Q-network, the policy network and the dynamics model."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch
from torch import nn
from torchrl.data import TensorSpec
from torchrl.modules import MLP, NoisyLinear

__all__ = ["init_linear_layers", "make_per_action_mlp", "noisy_layers"]


def noisy_layers(noise_std: float | None) -> dict:
    """The keyword arguments that make TorchRL's ``MLP`` (or ``MultiAgentMLP``) a NoisyNet at ``noise_std``; none for ``None``.

    Examples:
        >>> from torchrl.modules import MLP
        >>> from torchrl_mbe.modules.networks import noisy_layers
        >>> type(MLP(in_features=2, out_features=3, num_cells=[8], **noisy_layers(0.5))[0]).__name__
        'NoisyLinear'
    """
    return {} if noise_std is None else {"layer_class": NoisyLinear, "layer_kwargs": {"std_init": noise_std}}


def init_linear_layers(
    network: nn.Module,
    init_weight: Callable[[torch.Tensor], torch.Tensor] = nn.init.xavier_uniform_,
    init_bias: Callable[[torch.Tensor], torch.Tensor] = nn.init.zeros_,
) -> nn.Module:
    """Re-initializes every ``nn.Linear`` of ``network`` in place and returns it.

    The defaults are Keras' (Glorot-uniform weights, zero biases), which the paper's code used.
    TorchRL's ``NoisyLinear`` layers keep their own initialization (means and noise scales).

    Examples:
        >>> from torch import nn
        >>> from torchrl_mbe.modules import init_linear_layers
        >>> layer = init_linear_layers(nn.Linear(3, 2), init_bias=nn.init.ones_)
        >>> layer.bias.tolist()
        [1.0, 1.0]
    """
    for layer in network.modules():
        if isinstance(layer, nn.Linear) and not isinstance(layer, NoisyLinear):
            init_weight(layer.weight)
            init_bias(layer.bias)
    return network


def make_per_action_mlp(
    observation_size: int,
    action_spec: TensorSpec,
    num_cells: Sequence[int],
    activation_class: type[nn.Module] = nn.ReLU,
    init_weight: Callable[[torch.Tensor], torch.Tensor] = nn.init.xavier_uniform_,
    init_bias: Callable[[torch.Tensor], torch.Tensor] = nn.init.zeros_,
    device: torch.device | str = "cpu",
    noise_std: float | None = None,
) -> MLP:
    """An ``MLP`` from observations to one output per discrete action of ``action_spec``.

    Every layer's weights and biases start from ``init_weight`` and ``init_bias``
    (``nn.init`` functions, e.g. ``partial(nn.init.normal_, std=0.3)``). With
    ``noise_std``, the layers are TorchRL's ``NoisyLinear`` (a NoisyNet, its noise
    starting at that scale), which keep their own initialization.

    Examples:
        >>> import torch
        >>> from torchrl.data import OneHot
        >>> from torchrl_mbe.modules import make_per_action_mlp
        >>> make_per_action_mlp(2, OneHot(3), [16])(torch.zeros(5, 2)).shape
        torch.Size([5, 3])
        >>> type(make_per_action_mlp(2, OneHot(3), [16], noise_std=0.5)[0]).__name__
        'NoisyLinear'
    """
    network = MLP(
        in_features=observation_size,
        out_features=action_spec.space.n,
        num_cells=list(num_cells),
        activation_class=activation_class,
        device=device,
        **noisy_layers(noise_std),
    )
    return init_linear_layers(network, init_weight, init_bias)
