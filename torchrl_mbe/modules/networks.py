"""Network helpers shared by the Q-network, the policy network and the dynamics model, single or a population's.

A population's networks are TorchRL's ``MultiAgentMLP`` (``share_params=False``: every member's
parameters stacked ``[M, ...]``), as :class:`MembersMLP`, which multiplies them as batched
matrices, reading ``[*B, M, F]``: the member dimension ``M`` is the last batch dimension, right before the
features (docs/architecture.md, "Where the member dimension lives").
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModuleBase
from torch import nn
from torchrl.data import TensorSpec
from torchrl.modules import MLP, MultiAgentMLP, NoisyLinear, QValueActor

__all__ = [
    "MembersMLP",
    "action_values",
    "forward_on_hot_entries",
    "init_linear_layers",
    "make_members_mlp",
    "make_per_action_mlp",
    "make_population_q_actor",
    "member_state_dict",
    "noisy_layers",
    "reset_members_noise",
]


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


def make_population_q_actor(
    observation_size: int,
    action_spec: TensorSpec,
    num_cells: Sequence[int],
    num_members: int,
    *,
    input_norm: nn.Module | None = None,
    noise_std: float | None = None,
    device: torch.device | str = "cpu",
) -> QValueActor:
    """A ``QValueActor`` over ``num_members`` independent Q-networks: ``[*B, M, F]`` observations to ``[*B, M, A]`` values.

    The networks are :func:`make_members_mlp`'s (ReLU hidden layers ``num_cells``),
    each member initialized as :func:`~torchrl_mbe.modules.make_per_action_mlp`
    initializes the single Q-network; a population of one then starts from the
    weights a single network built from the same seed starts from.

    Args:
        observation_size (int): features per member.
        action_spec (TensorSpec): one member's discrete action spec (e.g. ``OneHot(A)``).
        num_cells (sequence of int): hidden layer widths.
        num_members (int): the population size ``M``.

    Keyword Args:
        input_norm (nn.Module, optional): applied to the observations first (a
            :class:`~torchrl_mbe.modules.Standardize` of shape ``(M, F)``: one set of statistics per member).
        noise_std (float, optional): NoisyNet members (see :func:`make_members_mlp`).
        device (torch.device or str): where the parameters live. Defaults to ``"cpu"``.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl.data import OneHot
        >>> from torchrl_mbe.modules.networks import make_population_q_actor
        >>> actor = make_population_q_actor(2, OneHot(3), [16], num_members=4)
        >>> out = actor(TensorDict(observation=torch.zeros(5, 4, 2), batch_size=[5, 4]))
        >>> out["action_value"].shape, out["action"].shape
        (torch.Size([5, 4, 3]), torch.Size([5, 4, 3]))
        >>> actor.module[0].params["0", "weight"].shape  # [M, hidden, features]
        torch.Size([4, 16, 2])
    """
    network = make_members_mlp(
        observation_size, action_spec.space.n, num_cells, num_members, noise_std=noise_std, device=device
    )
    if input_norm is not None:
        network = nn.Sequential(input_norm, network)
    return QValueActor(network, spec=action_spec, in_keys=["observation"])


class MembersMLP(MultiAgentMLP):
    """TorchRL's ``MultiAgentMLP`` whose linear layers multiply the members' stacked parameters as batched matrices.

    ``MultiAgentMLP`` calls its template network under ``torch.vmap``, swapping the
    stacked parameters in with ``to_module`` at every call, which costs more than a
    small member's forward (docs/performance.md, "The members' networks as batched
    products"). Here each layer is one ``torch.baddbmm`` over the members (on a CPU,
    what the vmapped layer computes, to the bit) and each activation is the
    template's module; the parameters, their initialization and the ``state_dict``
    are ``MultiAgentMLP``'s. A TorchRL ``NoisyLinear`` layer's weight and bias are
    its own properties (its noise where the exploration type asks for it), read with
    its stacked parameters swapped in. :attr:`batched_products` says whether the
    network computes so: a lazy, centralized or parameter-sharing network, one with
    tuple outputs or with layers of another kind takes ``MultiAgentMLP``'s call.
    Build it with :func:`make_members_mlp`.

    Examples:
        >>> import torch
        >>> from torchrl.modules import MultiAgentMLP
        >>> from torchrl_mbe.modules.networks import MembersMLP
        >>> kwargs = dict(n_agent_inputs=3, n_agent_outputs=2, n_agents=4, centralized=False, share_params=False)
        >>> network = MembersMLP(**kwargs, num_cells=[8])
        >>> vmapped = MultiAgentMLP(**kwargs, num_cells=[8])
        >>> _ = vmapped.load_state_dict(network.state_dict())
        >>> states = torch.randn(5, 4, 3)
        >>> network.batched_products, torch.equal(network(states), vmapped(states))
        (True, True)
    """

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.batched_products = (
            self.initialized
            and not self.centralized
            and not self.share_params
            and isinstance(self.n_agent_outputs, int)
            and all(
                (isinstance(module, nn.Linear) and module.bias is not None) or name not in self.params.keys()
                for name, module in self._empty_net.named_children()  # linear layers with a bias, and activations
            )
        )

    def forward(self, *inputs: torch.Tensor) -> torch.Tensor:
        if not self.batched_products:
            return super().forward(*inputs)
        features = self._pre_forward_check(torch.cat(inputs, -1) if len(inputs) > 1 else inputs[0])
        return self.forward_from(features, 0)

    def forward_from(self, hidden: torch.Tensor, start: int) -> torch.Tensor:
        """The template's modules from the ``start``-th on, applied to ``hidden`` ``[*B, M, C]`` (``[*B, M, out]``).

        Raises:
            ValueError: the network does not compute with :attr:`batched_products`.
        """
        if not self.batched_products:
            raise ValueError("forward_from needs a MembersMLP that computes with batched products (batched_products).")
        batch_shape, num_members = hidden.shape[:-2], hidden.shape[-2]
        hidden = hidden.reshape(-1, num_members, hidden.shape[-1]).transpose(0, 1)  # [M, N, C]
        for name, module in list(self._empty_net.named_children())[start:]:
            if isinstance(module, nn.Linear):
                weight, bias = self._stacked_weight_and_bias(name, module)
                hidden = torch.baddbmm(bias.unsqueeze(-2), hidden, weight.transpose(-1, -2))
            else:
                hidden = module(hidden)
        return hidden.transpose(0, 1).reshape(*batch_shape, num_members, hidden.shape[-1])

    def _stacked_weight_and_bias(self, name: str, module: nn.Linear) -> tuple[torch.Tensor, torch.Tensor]:
        """Layer ``name``'s ``[M, out, in]`` weights and ``[M, out]`` biases."""
        layer = self.params[name]
        if type(module) is nn.Linear:
            return layer["weight"], layer["bias"]
        # A NoisyLinear: its properties add the noise where TorchRL's rule says (a shallow copy: params is locked)
        with layer.clone(recurse=False).to_module(module, preserve_module_state=False):
            return module.weight, module.bias


def make_members_mlp(
    in_features: int,
    out_features: int,
    num_cells: Sequence[int],
    num_members: int,
    *,
    activation_class: type[nn.Module] = nn.ReLU,
    noise_std: float | None = None,
    glorot: bool = True,
    batched: bool = True,
    device: torch.device | str | None = "cpu",
) -> MultiAgentMLP:
    """``num_members`` independent MLPs as one :class:`MembersMLP` (a TorchRL ``MultiAgentMLP``): ``[*B, M, in_features]`` to ``[*B, M, out_features]``.

    ``MultiAgentMLP(share_params=False, centralized=False)`` stacks the members'
    parameters along a leading member dimension (``network.params``, e.g.
    ``("0", "weight")`` of shape ``[M, num_cells[0], in_features]``). Each member's
    slice is initialized as :func:`~torchrl_mbe.modules.init_linear_layers`
    initializes a single MLP (Glorot-uniform weights, the paper's Keras
    initialization, and zero biases), layer by layer and member by member from
    torch's global generator; with ``glorot=False`` each member keeps torch's default
    ``Linear`` initialization (a TorchRL ``MLP``'s). With ``noise_std`` the layers are TorchRL's
    ``NoisyLinear`` (each member a NoisyNet, its noise starting at that scale),
    which keep their own initialization; resample their noise with
    :func:`reset_members_noise`. With ``batched=False`` it is TorchRL's ``MultiAgentMLP``
    itself, which computes the same values through its vmapped call.

    Examples:
        >>> import torch
        >>> from torchrl_mbe.modules.networks import make_members_mlp
        >>> network = make_members_mlp(3, 2, [8], num_members=4)
        >>> network(torch.zeros(5, 4, 3)).shape, network.params["0", "weight"].shape
        (torch.Size([5, 4, 2]), torch.Size([4, 8, 3]))
    """
    network = (MembersMLP if batched else MultiAgentMLP)(
        n_agent_inputs=in_features,
        n_agent_outputs=out_features,
        n_agents=num_members,
        centralized=False,
        share_params=False,
        num_cells=list(num_cells),
        activation_class=activation_class,
        device=device,
        **noisy_layers(noise_std),
    )
    if not glorot:
        return network
    # get_stateful_net puts the stacked parameters themselves into a copy of one member's MLP
    # (MultiAgentNetBase's documented way to re-initialize them in place).
    with torch.no_grad():
        init_linear_layers(
            network.get_stateful_net(),
            _each_member(nn.init.xavier_uniform_),
            _each_member(nn.init.zeros_),
        )
    return network


def action_values(network: TensorDictModuleBase, observation: torch.Tensor) -> torch.Tensor:
    """A value network's one output (a value per action) on an observation tensor, ``(*batch, num_actions)``.

    Examples:
        >>> import torch
        >>> from tensordict.nn import TensorDictModule
        >>> from torchrl_mbe.modules.networks import action_values
        >>> action_values(TensorDictModule(torch.nn.Linear(2, 3), ["observation"], ["values"]), torch.zeros(5, 2)).shape
        torch.Size([5, 3])
    """
    inputs = TensorDict({network.in_keys[0]: observation}, observation.shape[:-1])
    return network(inputs).get(network.out_keys[0])


def forward_on_hot_entries(network: nn.Module, hot: torch.Tensor) -> torch.Tensor:
    """An MLP's (or a ``MembersMLP``'s) output on one-hot inputs given by the indices of their ones, ``hot`` ``[*B, (M,) E]``.

    The first layer sums the hot entries' weight columns, which is its product with the
    inputs; the rest of the network takes it from there (a ``MembersMLP``'s
    :meth:`~MembersMLP.forward_from`).

    Raises:
        TypeError: ``network`` is neither a batched-products ``MembersMLP`` nor a sequence that starts with a linear layer.
    """
    if isinstance(network, MembersMLP) and network.batched_products:
        first = network.params["0"]
        members = torch.arange(hot.shape[-2], device=hot.device).unsqueeze(-1)  # [M, 1]
        hidden = first["weight"][members, :, hot].sum(-2) + first["bias"]  # [*B, M, E, C] summed: [*B, M, C]
        return network.forward_from(hidden, 1)
    if isinstance(network, nn.Sequential) and isinstance(network[0], nn.Linear):
        first, *rest = network
        hidden = first.weight.T[hot].sum(-2) + first.bias
        for module in rest:
            hidden = module(hidden)
        return hidden
    raise TypeError(f"hot entries need an MLP whose first module is a linear layer, got {type(network).__name__}.")


def reset_members_noise(module: nn.Module) -> None:
    """Resamples the factorized noise of every ``NoisyLinear`` layer of a ``MultiAgentMLP``, each member's on its own.

    ``NoisyLinear.reset_noise`` on the stacked network would reach only its
    parameter-less template; this draws, for each member and layer, the
    ``f(x) = sign(x) sqrt(|x|)`` noise of TorchRL's ``reset_noise`` (Fortunato et
    al.'s factorized Gaussian) into the ``[M, ...]`` buffers in place, so the
    losses that hold them see the new sample. Pass it to ``module.apply`` as
    TorchRL's ``reset_noise``; modules other than a ``MultiAgentMLP`` are left alone.

    Examples:
        >>> import torch
        >>> from torchrl.envs.utils import ExplorationType, set_exploration_type
        >>> from torchrl_mbe.modules.networks import make_members_mlp, reset_members_noise
        >>> network = make_members_mlp(3, 2, [8], num_members=4, noise_std=0.5)
        >>> with set_exploration_type(ExplorationType.RANDOM):
        ...     before = network(torch.ones(4, 3))
        ...     _ = network.apply(reset_members_noise)
        ...     after = network(torch.ones(4, 3))
        >>> bool((before != after).all(-1).all())  # every member's output moved
        True
    """
    if not isinstance(module, MultiAgentMLP):
        return
    for layer in module.params.values():
        if "weight_epsilon" not in layer.keys():
            continue
        num_members, out_features, in_features = layer["weight_epsilon"].shape
        noise_in, noise_out = (
            _factorized_noise(num_members, size, layer["weight_epsilon"]) for size in (in_features, out_features)
        )
        layer["weight_epsilon"].copy_(noise_out[:, :, None] * noise_in[:, None, :])
        layer["bias_epsilon"].copy_(noise_out)


def _factorized_noise(num_members: int, size: int, like: torch.Tensor) -> torch.Tensor:
    """``[num_members, size]`` draws of ``sign(x) sqrt(|x|)``, ``x`` standard normal (``NoisyLinear._scale_noise``, per member)."""
    x = torch.randn(num_members, size, device=like.device, dtype=like.dtype)
    return x.sign() * x.abs().sqrt()


def _each_member(init: Callable[[torch.Tensor], torch.Tensor]) -> Callable[[torch.Tensor], torch.Tensor]:
    """Applies ``init`` to every member's slice of a stacked ``[M, ...]`` tensor (fan-in and fan-out are a member's)."""

    def init_each_member(stacked: torch.Tensor) -> torch.Tensor:
        for member in range(stacked.shape[0]):
            init(stacked[member])
        return stacked

    return init_each_member


def member_state_dict(population_state: dict[str, torch.Tensor], member: int) -> dict[str, torch.Tensor]:
    """Member ``member``'s slice of a population module's ``state_dict``, keyed as the single module's.

    A population module is the single module with each ``MultiAgentMLP`` in place of
    its ``MLP`` (parameters under ``params``, stacked ``[M, ...]``) and statistics of
    shape ``[M, ...]`` (:class:`~torchrl_mbe.modules.Standardize` ``(M, F)``): a
    member's entry is the ``[member]`` slice of every tensor, its key without
    ``params.``. The result loads into the single module (``make_q_actor``'s
    ``QValueActor`` for :func:`make_population_q_actor`'s), so a member's policy is
    saved and read as a single run's.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl.data import OneHot
        >>> from torchrl.modules import QValueActor
        >>> from torchrl_mbe.modules import make_per_action_mlp
        >>> from torchrl_mbe.modules.networks import make_population_q_actor, member_state_dict
        >>> population = make_population_q_actor(2, OneHot(3), [16], num_members=4)
        >>> single = QValueActor(make_per_action_mlp(2, OneHot(3), [16]), spec=OneHot(3), in_keys=["observation"])
        >>> _ = single.load_state_dict(member_state_dict(population.state_dict(), 2))
        >>> states = torch.randn(5, 4, 2)
        >>> values = population(TensorDict(observation=states, batch_size=[5, 4]))["action_value"][:, 2]
        >>> torch.allclose(single(TensorDict(observation=states[:, 2], batch_size=[5]))["action_value"], values)
        True
    """
    return {
        key.replace("params.", ""): value[member].clone()
        for key, value in population_state.items()
        if not value.is_meta  # a NoisyLinear template's buffers: MultiAgentMLP keeps them on the meta device
    }
