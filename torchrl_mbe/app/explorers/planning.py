"""The planning explorers: a dynamics model predicts each action's next state, a novelty scorer picks the rarest."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch
from omegaconf import DictConfig
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.data import OneHot, ReplayBuffer, TensorSpec

from torchrl_mbe.app.explorers.base import (
    EGreedyExplorer,
    ExplorationConfig,
    Explorer,
    ExplorerContext,
    QNetwork,
    eps_schedule,
    field_names,
)
from torchrl_mbe.app.optim import (
    GradientStep,
    UpdateSchedule,
    adam,
    load_target_state,
    make_target_updater,
    target_state,
)
from torchrl_mbe.app.replay import SUCCESSOR_KEY, SUCCESSOR_TERMINATED_KEY, flatten_frames, one_step_transitions
from torchrl_mbe.app.settings import NON_NEGATIVE, POSITIVE, POSITIVE_INT, Rule, setting
from torchrl_mbe.envs import resolve_env_id, task_of
from torchrl_mbe.envs.transforms import NoveltyReward
from torchrl_mbe.modules import novelty as scorers
from torchrl_mbe.modules.dynamics import DynamicsModel
from torchrl_mbe.modules.exploration import ModelBasedExplorationPolicy
from torchrl_mbe.modules.observations import hot_entries
from torchrl_mbe.modules.planner import NoveltyPlanner
from torchrl_mbe.modules.table import TableActionValue, TableNoveltyValue, TableValueIteration, TransitionTable
from torchrl_mbe.objectives import DynamicsLoss, NoveltyValueLoss
from torchrl_mbe.rundir import is_int

DYNAMICS = ("mlp", "oracle", "table")
"""``dynamics.name``: a learned network, the task's true dynamics, or a learned table of one-hot states."""


def table_refusal(cfg: DictConfig, observation_spec: TensorSpec) -> str | None:
    """Why ``dynamics=table`` cannot serve this run, or ``None``: it needs cells (one ``OneHot`` group), one run and one-step plans."""
    if hot_entries(observation_spec) != 1:
        return (
            f"{cfg.env.name} has no one-hot state (a OneHot observation: DeepSea, a Discrete space); use dynamics=mlp."
        )
    if cfg.population > 1:
        return "one table serves one run; use population=1 or dynamics=mlp."
    if cfg.exploration.horizon > 1:
        return "predicts from states, not from predictions; use exploration.horizon=1 or dynamics=mlp."
    return None


WINDOW = Rule(lambda v: is_int(v) and v >= 2, "an integer >= 2")
DISCOUNT = Rule(lambda v: 0 <= v < 1, "a number in [0, 1)")


@dataclass
class PlanningExploration(ExplorationConfig):
    """Explorers whose exploring steps plan with a dynamics model towards the rarest predicted state."""

    window: int = setting(50, Rule(WINDOW.test, "an integer >= 2 (the paper uses 50)"))
    horizon: int = setting(1, POSITIVE_INT)  # planning depth; >1 plans action sequences
    # random until the model is this good
    model_error_threshold: float | None = setting(None, NON_NEGATIVE.or_none())
    # the Q-network learns reward + coef * the scorer's novelty of each next state (0: the paper's, reward alone)
    intrinsic_coef: float = setting(0.0, NON_NEGATIVE)
    # an exploring step's action maximizes novelty + value_weight * Q (0: the paper's, novelty alone)
    value_weight: float = setting(0.0, NON_NEGATIVE)
    # a set discount: the novelty beyond each predicted state is learned (U) and added to it (null: the paper's, one step)
    novelty_discount: float | None = setting(None, DISCOUNT.or_none())


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


class NoveltyValueTraining:
    """The value of novelty's updates: one gradient step of :class:`~torchrl_mbe.objectives.NoveltyValueLoss` on each Q update's batch.

    Its target network is updated as the Q-network's (``algo.target_update``), and
    starts from the network as it is at the first update, input statistics fitted.
    """

    def __init__(self, loss: NoveltyValueLoss, algo: DictConfig, *, compile: bool, num_members: int | None) -> None:
        self.loss = loss
        self.step = GradientStep(
            lambda batch: loss(batch)["loss_novelty_value"],
            adam(loss.parameters(), algo.lr),
            algo.max_grad_norm,
            compile=compile,
            num_members=num_members,
        )
        self.target_updater = make_target_updater(algo, loss)
        self.updates = 0

    def update(self, batch: TensorDictBase) -> dict[str, float]:
        if self.updates == 0:
            self.loss.target_value_network_params.update_(self.loss.value_network_params)
        loss = self.step(batch)
        self.target_updater.step()
        self.updates += 1
        return {"loss_novelty_value": loss}

    def state_dict(self) -> dict:
        return {
            **target_state(self.loss, self.target_updater),
            "optimizer": self.step.optimizer.state_dict(),
            "updates": self.updates,
        }

    def load_state_dict(self, state: dict) -> None:
        load_target_state(self.loss, self.target_updater, state)
        self.step.optimizer.load_state_dict(state["optimizer"])
        self.updates = state["updates"]


class PlanningExplorer(EGreedyExplorer):
    """The paper's exploration: with probability eps, the action whose predicted next state the novelty scorer rates rarest.

    The policy is :class:`~torchrl_mbe.ModelBasedExplorationPolicy` around the actor;
    the dynamics model is a network (``dynamics=mlp``), a table of one-hot states
    written from every new frame (``dynamics=table``: :class:`~torchrl_mbe.modules.table.TransitionTable`)
    or the task's exact dynamics (``dynamics=oracle``: MountainCar's physics, DeepSea's
    grid; nothing to train). Its error on every new batch, before it is trained on,
    feeds the policy's warm-up switch. Subclasses choose the
    novelty scorer (``scorer``).
    """

    schema = PlanningExploration
    log_columns = ("loss_dynamics", "dynamics_val_error", "intrinsic_reward", "loss_novelty_value")
    counters = ("dynamics_updates",)
    scorer: ClassVar[type[scorers.RollingWindowNovelty]]  # the novelty scorer's class

    def __init__(
        self,
        policy: ModelBasedExplorationPolicy,
        loss: DynamicsLoss,
        training: DynamicsTraining | None,
        num_members: int | None = None,
        intrinsic_coef: float | None = None,
        novelty_value: NoveltyValueTraining | None = None,
    ) -> None:
        super().__init__(policy, policy)
        self.loss = loss
        self.training = training  # None for the oracle and the table, which have no gradient step
        self.novelty_value = novelty_value
        self.num_members = num_members
        self.intrinsic_coef = intrinsic_coef
        self.val_error: torch.Tensor | None = None  # float64, [M] in a population
        self.intrinsic_reward: list[float] | float | None = None  # the last batch's mean (each member's)

    @classmethod
    def build(cls, context: ExplorerContext) -> Explorer:
        cfg = context.cfg
        exploration = cfg.exploration
        if cfg.dynamics.name == "oracle":
            dynamics = task_of(resolve_env_id(cfg.env.name)).oracle(context.action_spec, **context.env_options)
        elif cfg.dynamics.name == "table":
            dynamics = TransitionTable(context.env.observation_spec, context.action_spec, device=context.device)
        else:
            dynamics = DynamicsModel(
                context.env.observation_spec,  # its size, and a MultiOneHot's groups
                context.action_spec,
                cfg.dynamics.num_cells,
                num_members=context.num_members,
                prior_scale=cfg.dynamics.prior_scale,
                prior_num_cells=cfg.dynamics.prior_num_cells,
                normalize=cfg.dynamics.normalize,
                output=cfg.dynamics.output,
                hot_entries=None
                if cfg.dynamics.normalize
                else hot_entries(context.env.observation_spec_unbatched["observation"]),
                device=context.device,
            )
        novelty = cls.make_novelty(
            exploration,
            context.env.observation_spec_unbatched["observation"],
            batch_shape=context.env.batch_size,
            device=context.action_spec.device,
        )
        planner = NoveltyPlanner(dynamics, novelty, context.action_spec, horizon=exploration.horizon)
        solved = cls.table_values(dynamics, novelty, cfg)
        policy = ModelBasedExplorationPolicy(
            context.actor,
            planner,
            **eps_schedule(cfg.algo),
            model_error_threshold=exploration.model_error_threshold,
            value_weight=exploration.value_weight,
            novelty_value=solved.get("novelty_value", context.novelty_value),
            action_value=solved.get("action_value"),
        )
        loss = DynamicsLoss(dynamics)
        loss.set_keys(next_observation=SUCCESSOR_KEY)
        training = (
            DynamicsTraining(dynamics, loss, cfg.dynamics, compile=cfg.compile)
            if isinstance(dynamics, DynamicsModel)
            else None
        )
        intrinsic_coef = exploration.intrinsic_coef or None
        if intrinsic_coef is not None:
            context.env.append_transform(NoveltyReward(novelty))
        return cls(
            policy, loss, training, context.num_members, intrinsic_coef, cls.novelty_value_training(context, planner)
        )

    @staticmethod
    def table_values(
        dynamics: TensorDictModuleBase, novelty: scorers.RollingWindowNovelty, cfg: DictConfig
    ) -> dict[str, TableValueIteration]:
        """What value iteration on a transition table solves for the policy: ``U`` (novelty discounted) and the weighed Q-values (``value_weight`` set)."""
        if not isinstance(dynamics, TransitionTable):
            return {}
        solved = {}
        if cfg.exploration.novelty_discount is not None:
            solved["novelty_value"] = TableNoveltyValue(dynamics, novelty, gamma=cfg.exploration.novelty_discount)
        if cfg.exploration.value_weight:
            solved["action_value"] = TableActionValue(dynamics, gamma=cfg.algo.gamma)
        return solved

    @classmethod
    def q_network(cls, cfg: DictConfig) -> QNetwork:
        """A network for ``U`` beside the Q-network when novelty is discounted, unless the table's value iteration solves ``U``."""
        return QNetwork(novelty_value=cfg.exploration.novelty_discount is not None and cfg.dynamics.name != "table")

    @staticmethod
    def novelty_value_training(context: ExplorerContext, planner: NoveltyPlanner) -> NoveltyValueTraining | None:
        """``U``'s training (``exploration.novelty_discount`` set), on replayed states scored against every env's window."""
        if context.novelty_value is None:
            return None
        loss = NoveltyValueLoss(
            context.novelty_value,
            planner.replayed_action_scores,
            context.action_spec,
            gamma=context.cfg.exploration.novelty_discount,
            loss_function=context.cfg.algo.loss_function,
            num_members=context.num_members,
        )
        return NoveltyValueTraining(
            loss, context.cfg.algo, compile=context.cfg.compile, num_members=context.num_members
        )

    @classmethod
    def make_novelty(
        cls, exploration: DictConfig, observation_spec: TensorSpec, **kwargs
    ) -> scorers.RollingWindowNovelty:
        """The novelty scorer, one window per environment (``kwargs``: ``batch_shape``, ``device``).

        ``scorer(observation_size, window, **options)``, its options :meth:`novelty_options`.
        """
        options = cls.novelty_options(exploration, observation_spec)
        return cls.scorer(observation_spec.shape[-1], exploration.window, **options, **kwargs)

    @classmethod
    def novelty_options(cls, exploration: DictConfig, observation_spec: TensorSpec) -> dict:
        """The scorer's options: the fields the explorer's schema adds to :class:`PlanningExploration` (the kernel's ``bandwidth``, kNN's ``k``)."""
        return {name: exploration[name] for name in field_names(cls.schema) - field_names(PlanningExploration)}

    @classmethod
    def method_label(cls, cfg: DictConfig, *, learns: bool) -> str:
        return cls.schema.name if cfg.dynamics.name == "mlp" else f"{cls.schema.name}-{cfg.dynamics.name}"

    def observe(self, batch: TensorDictBase) -> None:
        """The dynamics error on the new frames (not yet trained on), smoothed (each member's); feeds the warm-up switch."""
        frames = flatten_frames(one_step_transitions(batch), self.num_members)
        with torch.no_grad():
            error = self.loss(frames)["loss_dynamics"].double()
        self.val_error = error if self.val_error is None else 0.9 * self.val_error + 0.1 * error
        self.policy.report_model_error(float(self.val_error.max()))  # populations refuse model_error_threshold
        if isinstance(self.loss.dynamics, TransitionTable):  # a table learns each new frame as it comes
            keys = self.loss.tensor_keys
            self.loss.dynamics.write(
                frames[keys.observation],
                frames[keys.action],
                frames[keys.next_observation],
                frames[SUCCESSOR_TERMINATED_KEY],
                frames["next", "reward"],
            )
        for values in (self.policy.novelty_value, self.policy.action_value):
            if isinstance(values, TableValueIteration):
                values.refresh()
        if self.intrinsic_coef is not None:
            self.intrinsic_reward = member_means(batch.get(("next", "intrinsic_reward")), self.num_members)

    def learn(self, replay_buffer: ReplayBuffer, frames: int, new_frames: int) -> None:
        if self.training is not None:
            self.training.learn(replay_buffer, frames, new_frames)

    def after_q_update(self, batch: TensorDictBase) -> dict[str, float]:
        return self.novelty_value.update(batch) if self.novelty_value is not None else {}

    def log_fields(self) -> dict[str, float | None]:
        val_error = self.val_error.tolist() if self.val_error is not None else None
        return {
            "loss_dynamics": self.training.last_loss if self.training is not None else None,
            "dynamics_val_error": val_error,
            "intrinsic_reward": self.intrinsic_reward,
        }

    def summary_fields(self) -> dict[str, int]:
        return {"dynamics_updates": self.training.schedule.updates if self.training is not None else 0}

    def state_dict(self) -> dict:
        return {
            "val_error": self.val_error,
            "training": self.training.state_dict() if self.training is not None else None,
            "novelty_value": self.novelty_value.state_dict() if self.novelty_value is not None else None,
        }

    def load_state_dict(self, state: dict) -> None:
        self.val_error = state["val_error"]
        if self.training is not None:
            self.training.load_state_dict(state["training"])
        if self.novelty_value is not None:
            self.novelty_value.load_state_dict(state["novelty_value"])


@dataclass
class GaussianExploration(PlanningExploration):
    name: str = "gaussian"  # the paper: Gaussian fitted to the window


class GaussianExplorer(PlanningExplorer):
    """``exploration=gaussian``, the paper's: the least likely state under a full-covariance Gaussian of the window."""

    schema = GaussianExploration
    scorer = scorers.RollingGaussianDensity

    @classmethod
    def method_label(cls, cfg: DictConfig, *, learns: bool) -> str:
        if cfg.dynamics.name == "oracle":
            return "oracle"  # the paper's oracle experiment
        return super().method_label(cfg, learns=learns)


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
    window: int | None = setting(50, Rule(WINDOW.test, "an integer >= 2 (the paper uses 50)").or_none())
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


def member_means(values: torch.Tensor, num_members: int | None) -> list[float] | float:
    """The mean of a collected batch's entry: one per member (the batch is ``[num_envs, M, time, ...]``), or one."""
    if num_members is None:
        return float(values.mean())
    return values.transpose(0, 1).reshape(num_members, -1).mean(-1).tolist()


@dataclass
class CountsExploration(PlanningExploration):
    name: str = "counts"  # the count bonus 1 / sqrt(n + 1) of each state's bucket
    window: int | None = setting(None, WINDOW.or_none())  # null: every visit counts
    # SimHash's code length for an observation that is not one-hot (a one-hot one is counted exactly, by its hot index)
    bits: int = setting(16, Rule(lambda v: is_int(v) and 1 <= v <= 24, "an integer from 1 to 24"))


class CountsExplorer(PlanningExplorer):
    """``exploration=counts``: the state whose bucket was visited least (exact on a ``OneHot`` observation, SimHash on others)."""

    schema = CountsExploration
    scorer = scorers.VisitCounts

    @classmethod
    def novelty_options(cls, exploration: DictConfig, observation_spec: TensorSpec) -> dict:
        return {
            "bits": None if isinstance(observation_spec, OneHot) else exploration.bits
        }  # MultiOneHot: hashed, jointly


@dataclass
class DeepExploration(CountsExploration):
    # towards the rarest reachable state: the count bonus, and the learned novelty beyond each prediction
    name: str = "deep"
    novelty_discount: float | None = setting(0.99, DISCOUNT.or_none())


class DeepExplorer(CountsExplorer):
    """``exploration=deep``, deep model-based exploration: the action towards the rarest state reachable, not only the rarest next state.

    The counts planner (:class:`CountsExplorer`) plus ``U``, the discounted novelty beyond
    each predicted next state: an exploring step maximizes ``max(novelty(D(s, a)), U(s, a))``.
    A network learns ``U`` on the replayed transitions
    (:class:`~torchrl_mbe.objectives.NoveltyValueLoss`); with ``dynamics=table``, value
    iteration on the table solves it after each collected batch
    (:class:`~torchrl_mbe.modules.table.TableNoveltyValue`), and no network is built for it.
    """

    schema = DeepExploration
