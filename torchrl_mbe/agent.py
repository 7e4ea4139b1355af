"""Builds the agent of the training app from its Hydra config groups.

One function per part, each named after what it makes: the Q-network actor,
the dynamics model, the exploration policy the collector runs, the losses and
their optimizers. ``build_agent`` wires them together.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch
from omegaconf import DictConfig, OmegaConf
from tensordict.nn import TensorDictModuleBase, TensorDictSequential
from torch import nn
from torchrl.data import TensorSpec
from torchrl.envs import EnvBase
from torchrl.modules import MLP, QValueActor
from torchrl.objectives import DQNLoss, HardUpdate, SoftUpdate, TargetNetUpdater

from torchrl_mbe.density import GaussianKernelNovelty, RollingGaussianDensity, RollingWindowNovelty
from torchrl_mbe.dynamics import DynamicsModel
from torchrl_mbe.envs import resolve_env_id
from torchrl_mbe.exploration import AnnealedEGreedyModule, ModelBasedExplorationPolicy
from torchrl_mbe.objectives import DynamicsLoss
from torchrl_mbe.normalization import Standardize
from torchrl_mbe.oracle import MountainCarDynamics
from torchrl_mbe.planner import NoveltyPlanner

__all__ = ["Agent", "build_agent", "method_name", "make_per_action_mlp", "PLANNING_EXPLORERS"]

PLANNING_EXPLORERS = ("gaussian", "kernel")
"""Exploration options that plan with a dynamics model; ``egreedy`` and ``none`` do not."""


@dataclass
class Agent:
    """Everything a DQN run trains, saves and restores."""

    actor: QValueActor
    q_input_norm: Standardize | None  # fitted on the replay buffer before the first Q update
    policy: TensorDictModuleBase
    explorer: TensorDictModuleBase | None  # holds eps; its step() anneals it
    q_loss: DQNLoss
    target_updater: TargetNetUpdater
    q_optimizer: torch.optim.Optimizer
    dynamics_loss: DynamicsLoss | None
    dynamics_optimizer: torch.optim.Optimizer | None

    @property
    def eps(self) -> float:
        """The exploration rate now (0 without an explorer)."""
        return float(self.explorer.eps) if self.explorer is not None else 0.0

    @property
    def dynamics(self) -> TensorDictModuleBase | None:
        return self.dynamics_loss.dynamics if self.dynamics_loss is not None else None

    def state_dict(self) -> dict:
        state = {"policy": self.policy.state_dict(), "q_loss": self.q_loss.state_dict(), "q_optimizer": self.q_optimizer.state_dict()}
        if self.dynamics_optimizer is not None:
            state["dynamics_optimizer"] = self.dynamics_optimizer.state_dict()
        return state

    def load_state_dict(self, state: dict) -> None:
        self.policy.load_state_dict(state["policy"])
        self.q_loss.load_state_dict(state["q_loss"])
        self.q_optimizer.load_state_dict(state["q_optimizer"])
        if self.dynamics_optimizer is not None:
            self.dynamics_optimizer.load_state_dict(state["dynamics_optimizer"])


def method_name(cfg: DictConfig) -> str:
    """The name runs are grouped by in reports: ``dqn+gaussian``, ``explore:oracle``, ``reinforce``, ...

    Runs that never update the Q-network (``algo.updates_per_frame=0``, the
    exploration-only experiment) are named ``explore:<explorer>``. REINFORCE
    explores by sampling its policy, so the exploration group does not apply to it.
    """
    if cfg.algo.name == "reinforce":
        return "reinforce"
    explorer = cfg.exploration.name
    if explorer in PLANNING_EXPLORERS and cfg.dynamics.name == "oracle":
        explorer = f"{explorer}-oracle" if explorer != "gaussian" else "oracle"
    if cfg.algo.name == "dqn" and cfg.algo.updates_per_frame == 0:
        return "explore:" + ("random" if explorer == "egreedy" else explorer)
    return f"{cfg.algo.name}+{explorer}"


if not OmegaConf.has_resolver("method_name"):  # lets conf/ name run directories after the method
    OmegaConf.register_new_resolver("method_name", lambda *, _root_: method_name(_root_))


def build_agent(cfg: DictConfig, env: EnvBase) -> Agent:
    """The actor, the exploration policy, DQNLoss, target updater, dynamics loss and optimizers."""
    device = torch.device(cfg.device)
    action_spec = env.action_spec_unbatched.to(device)
    observation_size = env.observation_spec_unbatched["observation"].shape[-1]
    actor, q_input_norm = make_q_actor(
        observation_size, action_spec, cfg.algo.num_cells, device, standardize_inputs=cfg.algo.standardize_inputs
    )
    dynamics = make_dynamics(cfg, observation_size, action_spec, device)
    policy, explorer = make_exploration_policy(cfg, actor, dynamics, action_spec, observation_size, env.batch_size)
    q_loss = DQNLoss(
        actor,
        loss_function=cfg.loss.loss_function,
        double_dqn=cfg.loss.double_dqn,
        delay_value=True,
        action_space=action_spec,
    )
    q_loss.make_value_estimator(gamma=cfg.algo.gamma)
    learned = isinstance(dynamics, DynamicsModel)
    dynamics_loss = DynamicsLoss(dynamics) if dynamics is not None else None
    return Agent(
        actor=actor,
        q_input_norm=q_input_norm,
        policy=policy,
        explorer=explorer,
        q_loss=q_loss,
        target_updater=make_target_updater(cfg.loss, q_loss),
        q_optimizer=torch.optim.Adam(q_loss.parameters(), lr=cfg.optim.q_lr),
        dynamics_loss=dynamics_loss,
        dynamics_optimizer=torch.optim.Adam(dynamics.parameters(), lr=cfg.optim.dynamics_lr) if learned else None,
    )


def make_q_actor(
    observation_size: int, action_spec: TensorSpec, num_cells, device: torch.device, *, standardize_inputs: bool
) -> tuple[QValueActor, Standardize | None]:
    """``QValueActor(MLP)`` with Glorot-uniform weights (the paper's Keras initialization).

    With ``standardize_inputs`` the MLP reads standardized observations; the
    returned :class:`Standardize` is identity until the training loop fits it.
    """
    network = make_per_action_mlp(
        observation_size, action_spec, num_cells, nn.ReLU, nn.init.xavier_uniform_, nn.init.zeros_, device
    )
    if not standardize_inputs:
        return QValueActor(network, spec=action_spec, in_keys=["observation"]), None
    standardize = Standardize(observation_size, device=device)
    return QValueActor(nn.Sequential(standardize, network), spec=action_spec, in_keys=["observation"]), standardize


def make_per_action_mlp(
    observation_size: int,
    action_spec: TensorSpec,
    num_cells: Sequence[int],
    activation_class: type[nn.Module],
    init_weight: Callable[[torch.Tensor], torch.Tensor],
    init_bias: Callable[[torch.Tensor], torch.Tensor],
    device: torch.device | str = "cpu",
) -> MLP:
    """An ``MLP`` from observations to one output per discrete action.

    Every layer's weights and biases start from ``init_weight`` and ``init_bias``
    (``nn.init`` functions, e.g. ``partial(nn.init.normal_, std=0.3)``).
    """
    network = MLP(
        in_features=observation_size,
        out_features=action_spec.space.n,
        num_cells=list(num_cells),
        activation_class=activation_class,
        device=device,
    )
    for layer in network.modules():
        if isinstance(layer, nn.Linear):
            init_weight(layer.weight)
            init_bias(layer.bias)
    return network


def make_dynamics(cfg: DictConfig, observation_size: int, action_spec: TensorSpec, device: torch.device):
    """The dynamics model the planner uses, or ``None`` for explorers that do not plan."""
    if cfg.exploration.name not in PLANNING_EXPLORERS:
        return None
    if cfg.dynamics.name == "oracle":
        if resolve_env_id(cfg.env.name) != "MountainCar-v0":
            raise ValueError(f"dynamics=oracle exists for MountainCar-v0 only, not {cfg.env.name}.")
        return MountainCarDynamics(action_spec)
    return DynamicsModel(observation_size, action_spec, cfg.dynamics.num_cells, device=device)


def make_novelty(cfg: DictConfig, observation_size: int, batch_shape: torch.Size, device) -> RollingWindowNovelty:
    """The novelty scorer of ``cfg.exploration``, one window per environment."""
    kwargs = {"batch_shape": batch_shape, "device": device}
    if cfg.exploration.name == "gaussian":
        return RollingGaussianDensity(observation_size, cfg.exploration.window, **kwargs)
    return GaussianKernelNovelty(observation_size, cfg.exploration.window, bandwidth=cfg.exploration.bandwidth, **kwargs)


def make_exploration_policy(
    cfg: DictConfig,
    actor: QValueActor,
    dynamics,
    action_spec: TensorSpec,
    observation_size: int,
    env_batch_size: torch.Size,
) -> tuple[TensorDictModuleBase, TensorDictModuleBase | None]:
    """What the collector runs (greedy ``actor`` plus the configured exploration) and its eps holder."""
    algo, explorer = cfg.algo, cfg.exploration.name
    schedule = {
        "eps_init": algo.eps_init,
        "eps_end": algo.eps_end,
        "annealing_num_steps": algo.eps_annealing_frames,
        "schedule": algo.eps_schedule,
    }
    if explorer == "none":
        return actor, None
    if explorer == "egreedy":
        egreedy = AnnealedEGreedyModule(action_spec, **schedule)
        return TensorDictSequential(actor, egreedy), egreedy
    if explorer not in PLANNING_EXPLORERS:
        raise ValueError(f"Unknown exploration {explorer!r}; options: gaussian, kernel, egreedy, none.")
    novelty = make_novelty(cfg, observation_size, env_batch_size, action_spec.device)
    planner = NoveltyPlanner(dynamics, novelty, action_spec, horizon=cfg.exploration.horizon)
    policy = ModelBasedExplorationPolicy(
        actor, planner, **schedule, model_error_threshold=cfg.exploration.model_error_threshold
    )
    return policy, policy


def make_target_updater(loss_cfg: DictConfig, q_loss: DQNLoss) -> TargetNetUpdater:
    """TorchRL's ``HardUpdate`` (copy every N updates) or ``SoftUpdate`` (Polyak)."""
    if loss_cfg.target_update == "hard":
        return HardUpdate(q_loss, value_network_update_interval=loss_cfg.hard_update_interval)
    if loss_cfg.target_update == "soft":
        return SoftUpdate(q_loss, tau=loss_cfg.soft_update_tau)
    raise ValueError(f"loss.target_update must be 'hard' or 'soft', got {loss_cfg.target_update!r}.")
