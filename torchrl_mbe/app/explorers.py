"""The explorer registry: every ``exploration=`` option, its config schema and how it is built, in one place.

An explorer is a class here: its ``schema`` (the config dataclass of its
``exploration=`` option, registered with Hydra by :mod:`torchrl_mbe.app.config`)
and its :meth:`~Explorer.build`, which returns the explorer with a fixed shape:

* ``policy``: the TensorDictModule the collector runs (the greedy actor plus the exploring rule);
* ``eps``: the exploration rate now (0 for an explorer without one), annealed by :meth:`~Explorer.anneal`;
* hooks the DQN loop calls on every explorer alike: :meth:`~Explorer.observe` (fresh
  frames), :meth:`~Explorer.learn` (its own updates), :meth:`~Explorer.after_q_update`
  (on the Q update's batch), :meth:`~Explorer.log_fields`, :meth:`~Explorer.summary_fields`
  and its checkpoint state (:meth:`~Explorer.state_dict`).

The loop never asks which explorer it has. Adding one means adding a class here
(and its line in :data:`EXPLORERS`); see ``docs/architecture.md``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import ClassVar, Optional

import torch
from omegaconf import MISSING, DictConfig
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase, TensorDictSequential
from torchrl.data import ReplayBuffer, TensorSpec
from torchrl.envs import ExplorationType, TransformedEnv
from torchrl.envs.transforms import RNDTransform
from torchrl.modules import MLP, MultiAgentMLP, QValueActor, reset_noise
from torchrl.objectives import DQNLoss, RNDLoss

from torchrl_mbe.app.optim import GradientStep, UpdateSchedule, adam
from torchrl_mbe.app.replay import SUCCESSOR_KEY, flatten_frames, one_step_transitions
from torchrl_mbe.app.settings import LAYERS, NON_NEGATIVE, POSITIVE, POSITIVE_INT, PROBABILITY, Rule, setting
from torchrl_mbe.envs import resolve_env_id, task_of
from torchrl_mbe.envs.transforms import BootstrapHeads, PopulationRNDTransform
from torchrl_mbe.modules import novelty as scorers
from torchrl_mbe.modules.dynamics import DynamicsModel
from torchrl_mbe.modules.exploration import AnnealedEGreedyModule, ModelBasedExplorationPolicy
from torchrl_mbe.modules.networks import make_members_mlp, reset_members_noise
from torchrl_mbe.modules.planner import NoveltyPlanner
from torchrl_mbe.objectives import DynamicsLoss
from torchrl_mbe.objectives.population import PopulationRNDLoss
from torchrl_mbe.rundir import is_int

__all__ = [
    "EXPLORERS",
    "ExplorationConfig",
    "Explorer",
    "ExplorerContext",
    "PlanningExplorer",
    "explorer_of",
    "logged_columns",
    "logged_counters",
]

WINDOW = Rule(lambda v: is_int(v) and v >= 2, "an integer >= 2")


@dataclass
class ExplorationConfig:
    """The ``exploration`` group's common part: the option's name."""

    name: str = MISSING


@dataclass
class NoExploration(ExplorationConfig):
    name: str = "none"  # never explores: the greedy actor alone


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
    def q_network_noise(cls, exploration: DictConfig) -> float | None:
        """The initial noise scale of a NoisyNet Q-network this explorer needs, or ``None`` for a plain one."""
        return None

    @classmethod
    def q_ensemble(cls, exploration: DictConfig) -> tuple[int, float] | None:
        """The ``(heads, prior scale)`` of the Q ensemble this explorer acts with (Bootstrapped DQN), or ``None`` for one Q-network."""
        return None

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
    def q_network_noise(cls, exploration: DictConfig) -> float | None:
        return exploration.std_init

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


class BootstrapExplorer(Explorer):
    """``exploration=bootstrap``: the ensemble explores by acting with one head per episode (Thompson sampling).

    The Q-network is the ensemble (:meth:`q_ensemble`); the explorer appends
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
    def q_ensemble(cls, exploration: DictConfig) -> tuple[int, float] | None:
        return exploration.num_heads, exploration.prior_scale


@dataclass
class PlanningExploration(ExplorationConfig):
    """Explorers whose exploring steps plan with a dynamics model towards the rarest predicted state."""

    window: int = setting(50, Rule(WINDOW.test, "an integer >= 2 (the paper uses 50)"))
    horizon: int = setting(1, POSITIVE_INT)  # planning depth; >1 plans action sequences
    # random until the model is this good
    model_error_threshold: Optional[float] = setting(None, NON_NEGATIVE.or_none())


class DynamicsTraining:
    """The dynamics model's own updates, on its own :class:`~torchrl_mbe.app.optim.UpdateSchedule` (``dynamics.learning_starts``, ``dynamics.updates_per_frame``).

    Its input statistics are fitted on the replay buffer before the first update.
    """

    def __init__(self, model: DynamicsModel, loss: DynamicsLoss, dynamics: DictConfig, *, compile: bool) -> None:
        self.model = model
        self.step = GradientStep(
            lambda batch: loss(batch)["loss_dynamics"],
            adam(model.parameters(), dynamics.lr),
            dynamics.max_grad_norm,
            compile=compile,
            num_members=model.num_members,
        )
        self.schedule = UpdateSchedule(dynamics.learning_starts, dynamics.updates_per_frame)
        self.batch_size, self.last_loss = dynamics.batch_size, None

    def learn(self, replay_buffer: ReplayBuffer, frames: int, new_frames: int) -> None:
        for update in self.schedule.due(frames, new_frames):
            if update == 0:
                self.model.fit_normalization(replay_buffer, next_observation_key=SUCCESSOR_KEY)
            self.last_loss = self.update(replay_buffer)

    def update(self, replay_buffer: ReplayBuffer) -> float:
        """One gradient step on its own batch from the replay buffer."""
        return self.step(replay_buffer.sample(self.batch_size).exclude("index"))

    def state_dict(self) -> dict:
        return {
            "optimizer": self.step.optimizer.state_dict(),
            **self.schedule.state_dict(),
            "last_loss": self.last_loss,
        }

    def load_state_dict(self, state: dict) -> None:
        self.step.optimizer.load_state_dict(state["optimizer"])
        self.schedule.load_state_dict(state)
        self.last_loss = state["last_loss"]


class PlanningExplorer(EGreedyExplorer):
    """The paper's exploration: with probability eps, the action whose predicted next state the novelty scorer rates rarest.

    The policy is :class:`~torchrl_mbe.ModelBasedExplorationPolicy` around the actor;
    the dynamics model is learned (``dynamics=mlp``) or the task's exact dynamics
    (``dynamics=oracle``: MountainCar's physics, DeepSea's grid; nothing to train). Its error on every new batch, before
    it is trained on, feeds the policy's warm-up switch. Subclasses choose the
    novelty scorer (``scorer``).
    """

    schema = PlanningExploration
    log_columns = ("loss_dynamics", "dynamics_val_error")
    counters = ("dynamics_updates",)
    scorer: ClassVar[type[scorers.RollingWindowNovelty]]  # the novelty scorer's class

    def __init__(
        self,
        policy: ModelBasedExplorationPolicy,
        loss: DynamicsLoss,
        training: DynamicsTraining | None,
        num_members: int | None = None,
    ) -> None:
        super().__init__(policy, policy)
        self.loss = loss
        self.training = training  # None for the oracle, which has nothing to learn
        self.num_members = num_members
        self.val_error: torch.Tensor | None = None  # float64, [M] in a population

    @classmethod
    def build(cls, context: ExplorerContext) -> Explorer:
        cfg = context.cfg
        exploration = cfg.exploration
        if cfg.dynamics.name == "oracle":
            dynamics = task_of(resolve_env_id(cfg.env.name)).oracle(context.action_spec, **context.env_options)
        else:
            dynamics = DynamicsModel(
                context.observation_size,
                context.action_spec,
                cfg.dynamics.num_cells,
                num_members=context.num_members,
                prior_scale=cfg.dynamics.prior_scale,
                prior_num_cells=cfg.dynamics.prior_num_cells,
                normalize=cfg.dynamics.normalize,
                output=cfg.dynamics.output,
                device=context.device,
            )
        novelty = cls.make_novelty(
            exploration, context.observation_size, batch_shape=context.env.batch_size, device=context.action_spec.device
        )
        planner = NoveltyPlanner(dynamics, novelty, context.action_spec, horizon=exploration.horizon)
        policy = ModelBasedExplorationPolicy(
            context.actor, planner, **eps_schedule(cfg.algo), model_error_threshold=exploration.model_error_threshold
        )
        loss = DynamicsLoss(dynamics)
        loss.set_keys(next_observation=SUCCESSOR_KEY)
        training = (
            DynamicsTraining(dynamics, loss, cfg.dynamics, compile=cfg.compile)
            if isinstance(dynamics, DynamicsModel)
            else None
        )
        return cls(policy, loss, training, context.num_members)

    @classmethod
    def make_novelty(cls, exploration: DictConfig, observation_size: int, **kwargs) -> scorers.RollingWindowNovelty:
        """The novelty scorer, one window per environment (``kwargs``: ``batch_shape``, ``device``).

        ``scorer(observation_size, window, **options)``, its options the fields
        the explorer's schema adds to :class:`PlanningExploration` (the kernel's
        ``bandwidth``, kNN's ``k``).
        """
        options = {name: exploration[name] for name in _field_names(cls.schema) - _field_names(PlanningExploration)}
        return cls.scorer(observation_size, exploration.window, **options, **kwargs)

    @classmethod
    def method_label(cls, cfg: DictConfig, *, learns: bool) -> str:
        return f"{cls.schema.name}-oracle" if cfg.dynamics.name == "oracle" else cls.schema.name

    def observe(self, batch: TensorDictBase) -> None:
        """The dynamics error on the new frames (not yet trained on), smoothed (each member's); feeds the warm-up switch."""
        frames = flatten_frames(one_step_transitions(batch), self.num_members)
        with torch.no_grad():
            error = self.loss(frames)["loss_dynamics"].double()
        self.val_error = error if self.val_error is None else 0.9 * self.val_error + 0.1 * error
        self.policy.report_model_error(float(self.val_error.max()))  # populations refuse model_error_threshold

    def learn(self, replay_buffer: ReplayBuffer, frames: int, new_frames: int) -> None:
        if self.training is not None:
            self.training.learn(replay_buffer, frames, new_frames)

    def log_fields(self) -> dict[str, float | None]:
        val_error = self.val_error.tolist() if self.val_error is not None else None
        return {
            "loss_dynamics": self.training.last_loss if self.training is not None else None,
            "dynamics_val_error": val_error,
        }

    def summary_fields(self) -> dict[str, int]:
        return {"dynamics_updates": self.training.schedule.updates if self.training is not None else 0}

    def state_dict(self) -> dict:
        return {
            "val_error": self.val_error,
            "training": self.training.state_dict() if self.training is not None else None,
        }

    def load_state_dict(self, state: dict) -> None:
        self.val_error = state["val_error"]
        if self.training is not None:
            self.training.load_state_dict(state["training"])


@dataclass
class GaussianExploration(PlanningExploration):
    name: str = "gaussian"  # the paper: Gaussian fitted to the window


class GaussianExplorer(PlanningExplorer):
    """``exploration=gaussian``, the paper's: the least likely state under a full-covariance Gaussian of the window."""

    schema = GaussianExploration
    scorer = scorers.RollingGaussianDensity

    @classmethod
    def method_label(cls, cfg: DictConfig, *, learns: bool) -> str:
        return "oracle" if cfg.dynamics.name == "oracle" else cls.schema.name  # the paper's oracle experiment


@dataclass
class KernelExploration(PlanningExploration):
    name: str = "kernel"  # Oh et al. (2015): Gaussian-kernel similarity to the window
    bandwidth: float = setting(0.1, POSITIVE)


class KernelExplorer(PlanningExplorer):
    """``exploration=kernel``, the paper's baseline (Oh et al., 2015): the least similar state by a Gaussian kernel."""

    schema = KernelExploration
    scorer = scorers.GaussianKernelNovelty


@dataclass
class DiagonalExploration(PlanningExploration):
    name: str = "diagonal"  # a Gaussian without correlations
    # null: every visited state
    window: Optional[int] = setting(50, Rule(WINDOW.test, "an integer >= 2 (the paper uses 50)").or_none())
    # each dimension's variance floor: predictions off it by less than its root look familiar
    min_variance: float = setting(1e-8, POSITIVE)
    # added to each variance before the floor: keeps the order the floor ties
    added_variance: float = setting(0.0, NON_NEGATIVE)


class DiagonalExplorer(PlanningExplorer):
    """``exploration=diagonal``: a Gaussian of the window without correlations."""

    schema = DiagonalExploration
    scorer = scorers.DiagonalGaussianDensity


@dataclass
class KNearestExploration(PlanningExploration):
    name: str = "knn"  # mean scaled distance to the k nearest states of the window
    k: int = setting(5, POSITIVE_INT)


class KNearestExplorer(PlanningExplorer):
    """``exploration=knn``: the state farthest from its k nearest neighbours in the window."""

    schema = KNearestExploration
    scorer = scorers.KNearestNovelty


@dataclass
class KernelDensityExploration(PlanningExploration):
    name: str = "kde"  # kernel density estimate, Scott's-rule bandwidth per dimension
    window: int = setting(500, WINDOW)


class KernelDensityExplorer(PlanningExplorer):
    """``exploration=kde``: the least likely state under a kernel density estimate of the window."""

    schema = KernelDensityExploration
    scorer = scorers.KernelDensityNovelty


EXPLORERS: dict[str, type[Explorer]] = {
    explorer.schema.name: explorer
    for explorer in (
        GaussianExplorer,
        KernelExplorer,
        DiagonalExplorer,
        KNearestExplorer,
        KernelDensityExplorer,
        RNDExplorer,
        NoisyExplorer,
        BootstrapExplorer,
        EGreedyExplorer,
        Explorer,
    )
}
"""Every ``exploration=`` option by name: the planning ones (gaussian, kernel, diagonal, knn, kde),
TorchRL's RND and NoisyNet, Bootstrapped DQN with priors, e-greedy (random exploring actions) and none (never explores)."""


def logged_columns() -> tuple[str, ...]:
    """The updates table's columns of every registered explorer, in registry order (the run directory's header)."""
    return tuple(dict.fromkeys(column for explorer in EXPLORERS.values() for column in explorer.log_columns))


def logged_counters() -> tuple[str, ...]:
    """The summary's counters of every registered explorer, in registry order."""
    return tuple(dict.fromkeys(counter for explorer in EXPLORERS.values() for counter in explorer.counters))


def _field_names(schema: type) -> set[str]:
    return {spec.name for spec in dataclasses.fields(schema)}


def explorer_of(exploration: DictConfig) -> type[Explorer]:
    """The registered explorer of an ``exploration`` config (its name is one of :data:`EXPLORERS`, by the schema).

    Examples:
        >>> from omegaconf import OmegaConf
        >>> from torchrl_mbe.app.explorers import KernelExploration, explorer_of
        >>> explorer_of(OmegaConf.structured(KernelExploration())).__name__
        'KernelExplorer'
    """
    return EXPLORERS[exploration.name]
