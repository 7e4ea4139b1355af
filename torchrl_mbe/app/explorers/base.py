"""The explorer contract: its config schema, what it is built from, its hooks; e-greedy, the simplest explorer."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import ClassVar, NamedTuple

import torch
from omegaconf import MISSING, DictConfig
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule, TensorDictModuleBase, TensorDictSequential
from torchrl.data import ReplayBuffer, TensorSpec
from torchrl.envs import TransformedEnv
from torchrl.modules import QValueActor
from torchrl.objectives import DQNLoss

from torchrl_mbe.modules.exploration import AnnealedEGreedyModule


@dataclass
class ExplorationConfig:
    """The ``exploration`` group's common part: the option's name."""

    name: str = MISSING


@dataclass
class NoExploration(ExplorationConfig):
    name: str = "none"  # never explores: the greedy actor alone


class QEnsemble(NamedTuple):
    """The Q ensemble an explorer acts with (Bootstrapped DQN with randomized priors)."""

    num_heads: int  # K
    prior_scale: float  # Q_k = f_k + prior_scale * p_k
    num_cells: list[int]  # each head's (and its prior's) hidden layers


class QNetwork(NamedTuple):
    """The Q-network an explorer acts with, as :func:`~torchrl_mbe.app.dqn.make_q_actor` builds it: plain by default."""

    noise_std: float | None = None  # a NoisyNet's initial noise scale (NoisyNet)
    ensemble: QEnsemble | None = None  # heads in place of one network (Bootstrapped DQN)
    # a second network beside it, U: the novelty beyond each action (deep model-based exploration)
    novelty_value: bool = False


@dataclass
class ExplorerContext:
    """What an explorer is built from: the run's config, the training env and the Q side it explores for."""

    cfg: DictConfig
    env: TransformedEnv  # the training env (RND appends its transform to it)
    actor: QValueActor  # the greedy policy
    q_loss: DQNLoss
    action_spec: TensorSpec
    observation_size: int
    device: torch.device
    num_members: int | None = None  # a population's size M (the env batch is [num_envs, M]); None: one agent
    env_options: dict = dataclasses.field(default_factory=dict)  # the env's torch keyword arguments (DeepSea's size)
    novelty_value: TensorDictModule | None = None  # U, built as the Q-network is, when q_network asked for it


class Explorer:
    """``exploration=none``: the greedy actor acts alone; the base of every explorer, whose hooks do nothing.

    Subclasses set ``schema`` and override :meth:`build` and the hooks they need.
    """

    schema: ClassVar[type[ExplorationConfig]] = NoExploration
    log_columns: ClassVar[tuple[str, ...]] = ()  # the updates table's columns that log_fields and after_q_update fill
    counters: ClassVar[tuple[str, ...]] = ()  # the summary's counters that summary_fields returns
    intrinsic_coef: float | None = None  # the Q-network learns reward + intrinsic_coef * ("next", "intrinsic_reward")
    stored_keys: ClassVar[tuple] = ()  # keys of the collected frames the replay buffer keeps for this explorer's losses

    def __init__(self, policy: TensorDictModuleBase) -> None:
        self.policy = policy

    @classmethod
    def build(cls, context: ExplorerContext) -> Explorer:
        return cls(context.actor)

    @classmethod
    def q_network(cls, cfg: DictConfig) -> QNetwork:
        """The Q-network this run's explorer acts with: one plain network of ``algo.num_cells`` unless it says otherwise."""
        return QNetwork()

    @classmethod
    def method_label(cls, cfg: DictConfig, *, learns: bool) -> str:
        """How reports name runs of this explorer (after ``dqn+`` or ``explore:``)."""
        return cls.schema.name

    @property
    def eps(self) -> float:
        """The exploration rate now."""
        return 0.0

    def anneal(self, frames: int) -> None:
        """Advances the eps schedule by ``frames`` frames."""

    def observe(self, batch: TensorDictBase) -> None:
        """Sees freshly collected frames, before anything learns from them."""

    def learn(self, replay_buffer: ReplayBuffer, frames: int, new_frames: int) -> None:
        """The explorer's own updates that ``new_frames`` new frames pay for (``frames`` collected in all)."""

    def after_q_update(self, batch: TensorDictBase) -> dict[str, float]:
        """Runs after each Q update on its batch; returns losses to log."""
        return {}

    def log_fields(self) -> dict[str, float | None]:
        """Values for the updates table beside the losses."""
        return {}

    def summary_fields(self) -> dict[str, int]:
        """Counters for the run's summary."""
        return {}

    def state_dict(self) -> dict:
        """What a checkpoint keeps beyond the policy's own state (which travels with the policy)."""
        return {}

    def load_state_dict(self, state: dict) -> None:
        """Restores :meth:`state_dict`."""


def eps_schedule(algo: DictConfig) -> dict:
    """The keyword arguments of :class:`~torchrl_mbe.modules.AnnealedEGreedyModule`'s schedule, from ``algo``."""
    return {
        "eps_init": algo.eps_init,
        "eps_end": algo.eps_end,
        "annealing_num_steps": algo.eps_annealing_frames,
        "schedule": algo.eps_schedule,
    }


@dataclass
class EGreedyExploration(ExplorationConfig):
    name: str = "egreedy"  # uniformly random exploring actions


class EGreedyExplorer(Explorer):
    """``exploration=egreedy``: TorchRL's e-greedy after the actor, eps annealed by the algorithm's schedule."""

    schema = EGreedyExploration

    def __init__(self, policy: TensorDictModuleBase, eps_module: AnnealedEGreedyModule) -> None:
        super().__init__(policy)
        self.eps_module = eps_module

    @classmethod
    def build(cls, context: ExplorerContext) -> Explorer:
        egreedy = AnnealedEGreedyModule(
            context.action_spec, **eps_schedule(context.cfg.algo), device=context.action_spec.device
        )
        return cls(TensorDictSequential(context.actor, egreedy), egreedy)

    @classmethod
    def method_label(cls, cfg: DictConfig, *, learns: bool) -> str:
        return cls.schema.name if learns else "random"  # exploration only: random actions

    @property
    def eps(self) -> float:
        return float(self.eps_module.eps)

    def anneal(self, frames: int) -> None:
        self.eps_module.step(frames)


def field_names(schema: type) -> set[str]:
    """The field names of an explorer's config schema (a dataclass)."""
    return {spec.name for spec in dataclasses.fields(schema)}
