"""The baseline explorers: TorchRL's RND and NoisyNet, and Bootstrapped DQN with randomized priors."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from omegaconf import DictConfig
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.envs import ExplorationType
from torchrl.envs.transforms import RNDTransform
from torchrl.modules import MLP, MultiAgentMLP, reset_noise
from torchrl.objectives import RNDLoss

from torchrl_mbe.app.explorers.base import (
    EGreedyExplorer,
    ExplorationConfig,
    Explorer,
    ExplorerContext,
    QEnsemble,
    QNetwork,
)
from torchrl_mbe.app.optim import GradientStep, adam
from torchrl_mbe.app.settings import LAYERS, NON_NEGATIVE, POSITIVE, POSITIVE_INT, PROBABILITY, setting
from torchrl_mbe.envs.transforms import BootstrapHeads, PopulationRNDTransform
from torchrl_mbe.modules.networks import make_members_mlp, reset_members_noise
from torchrl_mbe.objectives.population import PopulationRNDLoss


@dataclass
class RNDExploration(ExplorationConfig):
    """Random network distillation (TorchRL's RNDTransform and RNDLoss): an intrinsic reward, e-greedy acting."""

    name: str = "rnd"
    intrinsic_coef: float = setting(0.5, NON_NEGATIVE)  # the reward learned from: extrinsic + coef * intrinsic
    num_cells: list[int] = setting([64, 64], LAYERS)  # target and predictor networks
    embedding_size: int = setting(64, POSITIVE_INT)
    lr: float = setting(1e-3, POSITIVE)  # predictor's Adam; one step per Q update, on the Q update's batch


class RNDExplorer(EGreedyExplorer):
    """``exploration=rnd``: e-greedy acting on reward plus TorchRL's RND bonus; the predictor learns on each Q batch.

    The transform is appended to the training env, so every collected frame carries
    ``("next", "intrinsic_reward")``; the loss normalizes observations with the
    transform's running statistics once they exist (after the first collected step).
    A population's members each have their own target, predictor and statistics
    (:class:`~torchrl_mbe.envs.transforms.PopulationRNDTransform` and :class:`~torchrl_mbe.objectives.population.PopulationRNDLoss`).
    """

    schema = RNDExploration
    log_columns = ("loss_rnd",)

    def __init__(
        self, policy, eps_module, rnd: RNDTransform, loss: RNDLoss, step: GradientStep, intrinsic_coef: float
    ) -> None:
        super().__init__(policy, eps_module)
        self.rnd, self.loss, self.step, self.intrinsic_coef = rnd, loss, step, intrinsic_coef

    @classmethod
    def build(cls, context: ExplorerContext) -> Explorer:
        egreedy = EGreedyExplorer.build(context)
        exploration, num_members = context.cfg.exploration, context.num_members
        target, predictor = (cls._network(context) for _ in range(2))
        transform, loss, loss_key = (
            (RNDTransform, RNDLoss, "loss_predictor")
            if num_members is None
            else (PopulationRNDTransform, PopulationRNDLoss, "member_loss")
        )
        rnd, loss = transform(target, predictor), loss(predictor, target)
        context.env.append_transform(rnd)
        step = GradientStep(
            lambda batch: loss(batch)[loss_key],
            adam(predictor.parameters(), exploration.lr),
            None,
            compile=context.cfg.compile,
            num_members=num_members,
        )
        return cls(egreedy.policy, egreedy.eps_module, rnd, loss, step, exploration.intrinsic_coef)

    @staticmethod
    def _network(context: ExplorerContext) -> MLP | MultiAgentMLP:
        """A target or predictor network: TorchRL's ``MLP`` (tanh, torch's default initialization), one per member in a population."""
        exploration = context.cfg.exploration
        in_features, out_features = context.observation_size, exploration.embedding_size
        if context.num_members is None:
            return MLP(
                in_features=in_features,
                out_features=out_features,
                num_cells=list(exploration.num_cells),
                activation_class=torch.nn.Tanh,
                device=context.device,
            )
        return make_members_mlp(
            in_features,
            out_features,
            exploration.num_cells,
            context.num_members,
            activation_class=torch.nn.Tanh,
            glorot=False,
            device=context.device,
        )

    def after_q_update(self, batch: TensorDictBase) -> dict[str, float]:
        """One step of the predictor, normalizing observations with the statistics the transform collects with."""
        if self.loss.obs_rms is None:  # the transform creates them at its first step
            self.loss.obs_rms = self.rnd.obs_rms
        return {"loss_rnd": self.step(batch)}

    def state_dict(self) -> dict:
        return {"rnd": self.rnd.state_dict(), "rnd_optimizer": self.step.optimizer.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        self.rnd.load_state_dict(state["rnd"])
        self.step.optimizer.load_state_dict(state["rnd_optimizer"])


@dataclass
class NoisyExploration(ExplorationConfig):
    """NoisyNet (TorchRL's NoisyLinear layers in the Q-network): learned parameter noise, no eps."""

    name: str = "noisy"
    std_init: float = setting(0.5, POSITIVE)  # initial noise scale of every layer


class NoisyExplorer(Explorer):
    """``exploration=noisy``: the Q-network's own noise explores; it is resampled after every Q update."""

    schema = NoisyExploration

    def __init__(self, policy: TensorDictModuleBase, num_members: int | None = None) -> None:
        super().__init__(policy)
        # a population's noise is stacked [M, ...]
        self.reset_noise = reset_noise if num_members is None else reset_members_noise

    @classmethod
    def build(cls, context: ExplorerContext) -> Explorer:
        context.q_loss.deterministic_sampling_mode = ExplorationType.RANDOM  # it learns through its noise, as it acts
        return cls(context.actor, context.num_members)

    @classmethod
    def q_network(cls, cfg: DictConfig) -> QNetwork:
        return QNetwork(noise_std=cfg.exploration.std_init)

    def after_q_update(self, batch: TensorDictBase) -> dict[str, float]:
        self.policy.apply(self.reset_noise)
        return {}


@dataclass
class BootstrapExploration(ExplorationConfig):
    """Bootstrapped DQN with randomized prior functions: K Q heads, one acting per episode, no eps (bsuite's boot_dqn)."""

    name: str = "bootstrap"
    num_heads: int = setting(20, POSITIVE_INT)  # the ensemble's size K
    prior_scale: float = setting(5.0, NON_NEGATIVE)  # Q_k = f_k + prior_scale * p_k, p_k fixed and random; 0: no priors
    mask_prob: float = setting(1.0, PROBABILITY)  # each head's chance of training on a transition
    num_cells: list[int] = setting(
        [50, 50], LAYERS
    )  # each head's and prior's hidden layers (in place of algo.num_cells)


class BootstrapExplorer(Explorer):
    """``exploration=bootstrap``: the ensemble explores by acting with one head per episode (Thompson sampling).

    The Q-network is the ensemble (:meth:`q_network`); the explorer appends
    :class:`~torchrl_mbe.envs.transforms.BootstrapHeads` to the training env, which draws
    each episode's head and each transition's bootstrap mask.
    """

    schema = BootstrapExploration
    stored_keys = (("next", "bootstrap_mask"),)  # each transition's mask, which the loss reads

    @classmethod
    def build(cls, context: ExplorerContext) -> Explorer:
        exploration = context.cfg.exploration
        context.env.append_transform(BootstrapHeads(exploration.num_heads, exploration.mask_prob))
        return cls(context.actor)

    @classmethod
    def q_network(cls, cfg: DictConfig) -> QNetwork:
        exploration = cfg.exploration
        return QNetwork(ensemble=QEnsemble(exploration.num_heads, exploration.prior_scale, list(exploration.num_cells)))
