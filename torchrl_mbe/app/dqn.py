"""DQN with model-based exploration (the paper's Algorithm 1): the agent built from config, and its loop.

:func:`train_dqn` reads top to bottom: collect a batch with the exploration
policy, store its transitions (n-step, through TorchRL's ``MultiStepTransform``),
record it, let the agent learn from the new frames (the explorer's own updates,
then the Q steps with their target update and eps annealing), then the runs'
bookkeeping (:mod:`torchrl_mbe.app.population`; a single run is a population of one).
:class:`DQNTraining` holds what the loop trains with, built for the members its batch
holds, and built again when members stop. What differs between explorers lives in
:mod:`torchrl_mbe.app.explorers`; the loop calls the explorer's hooks.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from pathlib import Path

import torch
from omegaconf import DictConfig
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.collectors import Collector
from torchrl.data import ReplayBuffer, TensorDictPrioritizedReplayBuffer, TensorSpec
from torchrl.envs import EnvBase, TransformedEnv
from torchrl.modules import QValueActor
from torchrl.objectives import DQNLoss, TargetNetUpdater

from torchrl_mbe.app.environments import env_options, make_run_env
from torchrl_mbe.app.explorers import Explorer, ExplorerContext, QNetwork, explorer_of
from torchrl_mbe.app.members import select_members
from torchrl_mbe.app.optim import (
    GradientStep,
    UpdateSchedule,
    adam,
    load_target_state,
    make_target_updater,
    target_state,
)
from torchrl_mbe.app.population import Resumable, StopOnInterrupt, open_population, start_population
from torchrl_mbe.app.replay import ReplayState, ReplayTransitions, make_replay_buffer
from torchrl_mbe.app.rollout import CollectorState
from torchrl_mbe.modules.bootstrap import BootstrappedQValueActor, EnsembleQNetwork
from torchrl_mbe.modules.networks import make_per_action_mlp, make_population_q_actor
from torchrl_mbe.modules.normalization import Standardize
from torchrl_mbe.modules.observations import hot_entries
from torchrl_mbe.objectives.bootstrap import BootstrapDQNLoss
from torchrl_mbe.objectives.population import PopulationDQNLoss

__all__ = ["DQNAgent", "DQNSettings", "build_dqn_agent", "member_dimension", "train_dqn"]


def train_dqn(cfg: DictConfig, run_dir: Path) -> dict:
    """Trains DQN with the configured exploration (``population=M`` agents together) and returns the summary.

    A single run is a population of one: the same loop, without a member dimension.
    When members stop, the parts are built again for the members still training,
    which go on from their own state (:meth:`~torchrl_mbe.app.population.Population.leave_batch`).
    """
    start = start_population(cfg, run_dir)  # the members a resumed checkpoint's batch keeps, or all
    training = DQNTraining(cfg, start.num_members)
    population = open_population(cfg, run_dir, training.agent, start)
    for name, part in training.parts().items():
        population.keep(name, part)
    with StopOnInterrupt() as interrupt:
        while population.training(interrupt):
            if population.holds_stopped_members():
                stopped_batch, training = training, population.leave_batch(partial(DQNTraining, cfg))
                stopped_batch.collector.shutdown()
            batch = next(training.batches)  # (num_envs, time), or (num_envs, M, time)
            stored = training.transitions(batch)
            if stored is not None:  # None while the first n-step windows fill
                training.replay_buffer.extend(stored)
            population.record(batch, eps=training.agent.eps)
            population.record_updates(training.agent.learn(batch, training.replay_buffer, population.frames))
            population.evaluate_and_checkpoint_if_due(batch.numel() // population.width)
    try:
        return population.finish(interrupt)  # its checkpoint keeps the collector's state
    finally:
        training.collector.shutdown()


class DQNTraining:
    """What the loop trains with, for the members its batch holds: the agent, the replay buffer, the n-step transitions, the collector.

    Args:
        cfg (DictConfig): the run's config.
        num_members (int, optional): the members the batch holds (``None`` for a single run).
    """

    def __init__(self, cfg: DictConfig, num_members: int | None) -> None:
        env = make_run_env(cfg, num_envs=cfg.env.num_envs, seed=cfg.seed, num_members=num_members)
        self.agent = build_dqn_agent(cfg, env)
        self.replay_buffer = make_replay_buffer(cfg.buffer, cfg.device, num_members)
        self.transitions = ReplayTransitions(
            cfg.algo.n_steps,
            cfg.algo.gamma,
            intrinsic_coef=self.agent.explorer.intrinsic_coef,
            num_members=num_members,
            extra_keys=self.agent.explorer.stored_keys,
        )
        # Built before a resume restores torch's generator: checking the policy draws from it.
        self.collector = Collector(
            env,
            self.agent.explorer.policy,
            frames_per_batch=cfg.collector.frames_per_batch * (num_members or 1),
            total_frames=-1,
        )
        self.batches = iter(self.collector)

    def parts(self) -> dict[str, Resumable]:
        """The parts whose state checkpoints keep beside the agent's."""
        return {
            "replay_buffer": ReplayState(self.replay_buffer),
            "transitions": self.transitions,  # the frames its n-step windows hold back
            "collector": CollectorState(self.collector),  # the env and the step it goes on from
        }


@dataclass(frozen=True)
class DQNSettings:
    """The Q side's schedule, read from ``algo`` (and the logger's period) once, when the agent is built."""

    learning_starts: int
    updates_per_frame: float
    batch_size: int
    lr: float
    lr_decay_frames: int | None
    lr_end_factor: float
    log_every_updates: int  # 0: no updates-table rows
    population: int  # agents learning together in the batch (1: a single run)

    @classmethod
    def from_config(cls, cfg: DictConfig, num_members: int | None = None) -> DQNSettings:
        """The settings of ``cfg`` for an agent of ``num_members`` members (``None``: a single agent)."""
        algo = cfg.algo
        return cls(
            algo.learning_starts,
            algo.updates_per_frame,
            algo.batch_size,
            algo.lr,
            algo.lr_decay_frames,
            algo.lr_end_factor,
            cfg.logger.log_every_updates,
            num_members or 1,
        )


class DQNAgent:
    """Everything a DQN run trains, saves and restores: the greedy actor, its explorer and the Q learning.

    Args:
        actor (QValueActor): the greedy policy.
        explorer (Explorer): the exploration rule around ``actor`` (see :mod:`torchrl_mbe.app.explorers`).
        q_loss (DQNLoss): TorchRL's DQN loss, with the target network.
        target_updater (TargetNetUpdater): steps after every Q update.
        q_step (GradientStep): DQNLoss, clipping, Adam.
        q_input_norm (Standardize): the Q-network's input statistics, fitted on
            the replay buffer before the first Q update (identity when
            ``algo.standardize_inputs=false``: never part of the network then).
        settings (DQNSettings): the Q side's schedule.
    """

    def __init__(
        self,
        actor: QValueActor,
        explorer: Explorer,
        q_loss: DQNLoss,
        target_updater: TargetNetUpdater,
        q_step: GradientStep,
        q_input_norm: Standardize,
        settings: DQNSettings,
    ) -> None:
        self.actor, self.explorer, self.q_loss, self.target_updater, self.q_step = (
            actor,
            explorer,
            q_loss,
            target_updater,
            q_step,
        )
        self.q_input_norm, self.settings = q_input_norm, settings
        self.standardizes_inputs = any(module is q_input_norm for module in actor.modules())
        self.population_size = settings.population  # a population's agents learn together, each from its own frames
        self.q_schedule = UpdateSchedule(settings.learning_starts, settings.updates_per_frame)

    @property
    def q_updates(self) -> int:
        """Q updates taken so far."""
        return self.q_schedule.updates

    @property
    def eps(self) -> float:
        """The exploration rate now (0 for an explorer without one)."""
        return self.explorer.eps

    def learn(self, batch: TensorDictBase, replay_buffer: ReplayBuffer, frames: int) -> list[dict]:
        """The updates that the new ``batch`` pays for (``frames`` collected in all, the batch included).

        The explorer sees the batch and takes its own updates; after
        ``learning_starts`` frames eps anneals and the Q-network takes its
        updates (:meth:`learn_q`). In a population, ``frames`` and the schedule
        count each member's frames, and a row's losses are lists (one per member).
        """
        new_frames = batch.numel() // self.population_size
        self.explorer.observe(batch)
        self.explorer.learn(replay_buffer, frames, new_frames)
        if frames >= self.settings.learning_starts:
            self.explorer.anneal(min(new_frames, frames - self.settings.learning_starts))
        return self.learn_q(replay_buffer, frames, new_frames)

    def learn_q(self, replay_buffer: ReplayBuffer, frames: int, new_frames: int) -> list[dict]:
        """The Q updates that ``new_frames`` more frames pay for: ``updates_per_frame`` each after ``learning_starts``.

        Returns a row of the updates table every ``log_every_updates`` Q updates.
        """
        settings = self.settings
        if frames < settings.learning_starts or not len(replay_buffer):  # n-step windows hold the last n frames back
            return []
        for group in self.q_step.optimizer.param_groups:
            group["lr"] = q_learning_rate(settings, frames)
        rows = []
        for update in self.q_schedule.due(frames, new_frames):
            if update == 0 and self.standardizes_inputs:
                fit_q_input_norm(self, replay_buffer)
            losses = update_q(self, replay_buffer)
            if settings.log_every_updates and (update + 1) % settings.log_every_updates == 0:
                rows.append(
                    {
                        "frames": frames,
                        "updates": update + 1,
                        **losses,
                        **self.explorer.log_fields(),
                        "eps": self.eps,
                    }
                )
        return rows

    def summary_fields(self) -> dict[str, int]:
        """The update counts of the run's summary."""
        return {"q_updates": self.q_updates, **self.explorer.summary_fields()}

    def state_dict(self) -> dict:
        """The policy (Q-network, exploration, dynamics, window) once, the target network, the optimizers, the counters."""
        return {
            "policy": self.explorer.policy.state_dict(),
            **target_state(self.q_loss, self.target_updater),
            "q_optimizer": self.q_step.optimizer.state_dict(),
            "q_updates": self.q_schedule.updates,
            "q_update_credit": self.q_schedule.credit,
            "explorer": self.explorer.state_dict(),
        }

    def select_members(self, state: dict, index: list[int], num_members: int) -> dict:
        """A population agent's :meth:`state_dict` with only the members ``index``, for this agent (built for ``len(index)``).

        Each tensor is cut where this agent's own differs in shape; the optimizers' moments,
        which a new optimizer does not hold yet, along their parameters' member dimension 0.
        """
        return select_members(state, index, num_members, like=self.state_dict())

    def load_state_dict(self, state: dict) -> None:
        self.explorer.policy.load_state_dict(state["policy"])
        load_target_state(self.q_loss, self.target_updater, state)
        self.q_step.optimizer.load_state_dict(state["q_optimizer"])
        self.q_schedule.load_state_dict({"updates": state["q_updates"], "credit": state["q_update_credit"]})
        self.explorer.load_state_dict(state["explorer"])


def build_dqn_agent(cfg: DictConfig, env: TransformedEnv) -> DQNAgent:
    """The actor, DQNLoss with its target updater and optimizer, and the configured explorer around the actor.

    Examples:
        >>> from pathlib import Path
        >>> from hydra import compose, initialize_config_dir
        >>> import torchrl_mbe
        >>> from torchrl_mbe import make_env
        >>> from torchrl_mbe.app import register_configs
        >>> from torchrl_mbe.app.dqn import build_dqn_agent
        >>> register_configs()
        >>> conf = Path(torchrl_mbe.__file__).resolve().parents[1] / "conf"
        >>> with initialize_config_dir(str(conf), version_base="1.3"):
        ...     cfg = compose("config", overrides=["exploration=rnd"])
        >>> env = make_env("mountaincar", num_envs=4, seed=0)
        >>> agent = build_dqn_agent(cfg, env)  # RND appends its transform to the training env
        >>> type(agent.explorer).__name__, env.rollout(3)["next", "intrinsic_reward"].shape
        ('RNDExplorer', torch.Size([4, 3, 1]))
    """
    algo, device, num_members = cfg.algo, torch.device(cfg.device), member_dimension(cfg, env)
    explorer_class = explorer_of(cfg.exploration)
    action_spec = env.action_spec_unbatched.to(device)
    observation_size = env.observation_spec_unbatched["observation"].shape[-1]
    q_input_norm = Standardize(
        observation_size if num_members is None else (num_members, observation_size), device=device
    )
    q_network = explorer_class.q_network(cfg)
    ensemble = q_network.ensemble  # a Bootstrapped DQN's heads, else None
    observation_spec = env.observation_spec_unbatched["observation"]
    q_actor = partial(
        make_q_actor,
        observation_size,
        action_spec,
        algo.num_cells,
        device,
        input_norm=q_input_norm if algo.standardize_inputs else None,
        num_members=num_members,
    )  # the Q-network, and the value of novelty beside it when the explorer asks for one
    actor = q_actor(q_network=q_network, hot_entries=None if algo.standardize_inputs else hot_entries(observation_spec))
    q_loss = make_q_loss(actor, algo, action_spec, num_members)
    novelty_value = make_novelty_value_network(q_actor()) if q_network.novelty_value else None
    context = ExplorerContext(
        cfg,
        env,
        actor,
        q_loss,
        action_spec,
        observation_size,
        device,
        num_members,
        env_options(cfg.env),
        novelty_value,
    )
    explorer = explorer_class.build(context)
    loss_key = "member_loss" if isinstance(q_loss, PopulationDQNLoss) else "loss"
    q_step = GradientStep(
        lambda batch: q_loss(batch)[loss_key],
        adam(q_loss.parameters(), algo.lr),
        algo.max_grad_norm,
        compile=cfg.compile,
        num_members=num_members if ensemble is None else ensemble.num_heads * (num_members or 1),  # heads clip alone
        heads_per_member=None if ensemble is None else ensemble.num_heads,
    )
    return DQNAgent(
        actor,
        explorer,
        q_loss,
        make_target_updater(algo, q_loss),
        q_step,
        q_input_norm,
        DQNSettings.from_config(cfg, num_members),
    )


def member_dimension(cfg: DictConfig, env: EnvBase) -> int | None:
    """The members ``env`` holds with ``population=M > 1`` (its batch's last size: M, fewer once members left); ``None`` for a single agent."""
    return env.batch_size[-1] if cfg.population > 1 else None


def make_q_actor(
    observation_size: int,
    action_spec: TensorSpec,
    num_cells,
    device: torch.device,
    *,
    input_norm: Standardize | None = None,
    num_members: int | None = None,
    q_network: QNetwork | None = None,
    hot_entries: int | None = None,
) -> QValueActor | BootstrappedQValueActor:
    """``QValueActor(MLP)`` with Glorot-uniform weights (the paper's Keras initialization), as the explorer's ``q_network`` asks.

    With ``input_norm`` the MLP reads observations standardized by it; with
    ``num_members`` it is a population's (:func:`~torchrl_mbe.modules.networks.make_population_q_actor`).
    With ``q_network.noise_std`` (``None``: a plain network) the MLP is a NoisyNet (see :func:`~torchrl_mbe.modules.make_per_action_mlp`);
    with ``q_network.ensemble`` it is a Bootstrapped DQN's (:class:`~torchrl_mbe.modules.bootstrap.BootstrappedQValueActor`,
    of ``ensemble.num_cells`` in place of ``num_cells``; one ensemble per member with ``num_members``; its
    first layer reads raw one-hot codes by their ``hot_entries`` ones, see :class:`EnsembleQNetwork`).
    """
    q_network = q_network or QNetwork()
    ensemble, noise_std = q_network.ensemble, q_network.noise_std
    if ensemble is not None:
        network = EnsembleQNetwork(
            observation_size,
            action_spec.space.n,
            ensemble.num_cells,
            ensemble.num_heads,
            ensemble.prior_scale,
            input_norm=input_norm,
            num_members=num_members,
            hot_entries=hot_entries,
            device=device,
        )
        return BootstrappedQValueActor(network, action_spec)
    if num_members is not None:
        return make_population_q_actor(
            observation_size,
            action_spec,
            num_cells,
            num_members,
            input_norm=input_norm,
            noise_std=noise_std,
            device=device,
        )
    network = make_per_action_mlp(observation_size, action_spec, num_cells, device=device, noise_std=noise_std)
    if input_norm is not None:
        network = nn.Sequential(input_norm, network)
    return QValueActor(network, spec=action_spec, in_keys=["observation"])


def make_novelty_value_network(actor: QValueActor) -> TensorDictModule:
    """A plain Q actor's network as the value of novelty ``U``: observation to ``"novelty_value"``, one per action.

    Built by :func:`make_q_actor`, so it reads the observation as the Q-network does (its input
    statistics, a population's members).
    """
    return TensorDictModule(actor.module[0].module, in_keys=actor.module[0].in_keys, out_keys=["novelty_value"])


def make_q_loss(
    actor: QValueActor | BootstrappedQValueActor, algo: DictConfig, action_spec: TensorSpec, num_members: int | None
) -> DQNLoss:
    """TorchRL's ``DQNLoss`` (one loss per member for a population's actor, per head for an ensemble's), its value estimator set.

    Its input keys are resolved now: ``DQNLoss`` does so lazily on first use, which would make a compiled step trace twice.
    """
    options = {
        "loss_function": algo.loss_function,
        "double_dqn": algo.double_dqn,
        "delay_value": True,
        "action_space": action_spec,
    }
    if isinstance(actor, BootstrappedQValueActor):
        q_loss = BootstrapDQNLoss(actor, **options)
    elif num_members is not None:
        q_loss = PopulationDQNLoss(actor, **options)
    else:
        q_loss = DQNLoss(actor, **options)
    q_loss.make_value_estimator(gamma=algo.gamma)  # with n-step transitions it discounts by gamma ** steps_to_next_obs
    _ = q_loss.in_keys
    return q_loss


def q_learning_rate(schedule: DQNSettings | DictConfig, frames: int) -> float:
    """``lr``, decayed linearly to ``lr * lr_end_factor`` over ``lr_decay_frames`` frames after ``learning_starts``.

    A function of the frame count, so a resumed run continues the same schedule.
    """
    if schedule.lr_decay_frames is None:
        return schedule.lr
    done = min(max(frames - schedule.learning_starts, 0) / schedule.lr_decay_frames, 1.0)
    return schedule.lr * (1.0 - done * (1.0 - schedule.lr_end_factor))


@torch.no_grad()
def fit_q_input_norm(agent: DQNAgent, replay_buffer: ReplayBuffer) -> None:
    """Fits the Q-network's input statistics once, on what the buffer holds, and gives them to the target network.

    Target updaters copy parameters, not buffers; the statistics never change
    after this fit, so copying them here keeps both networks consistent.
    """
    agent.q_input_norm.fit(replay_buffer[: len(replay_buffer)]["observation"])
    agent.q_loss.target_value_network_params.update_(agent.q_loss.value_network_params)


def update_q(agent: DQNAgent, replay_buffer: ReplayBuffer) -> dict[str, float]:
    """One DQN gradient step (TorchRL's DQNLoss), a target-network update, then the explorer's hook on the same batch.

    Returns the losses: ``loss_q``, and whatever the explorer's hook returns (RND: ``loss_rnd``).
    """
    sample = replay_buffer.sample(agent.settings.batch_size)
    batch = sample.exclude("index")  # the same keys at every call, so a compiled step is traced once
    losses = {"loss_q": agent.q_step(batch)}
    agent.target_updater.step()
    losses.update(agent.explorer.after_q_update(batch))
    if isinstance(replay_buffer, TensorDictPrioritizedReplayBuffer):
        sample.set("td_error", batch.get("td_error"))
        replay_buffer.update_tensordict_priority(sample)
    return losses
