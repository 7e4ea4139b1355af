"""DQN with model-based exploration (the paper's Algorithm 1): the agent built from config, and its loop.

:func:`train_dqn` reads top to bottom: collect a batch with the exploration
policy, store its transitions (n-step, through TorchRL's ``MultiStepTransform``),
check the dynamics model on the new frames, take the updates the frames pay for
(dynamics steps, Q steps with their target update, eps annealing), then the
run's bookkeeping (:mod:`torchrl_mbe.app.run`).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import torch
from omegaconf import DictConfig
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase, TensorDictSequential
from torch import nn
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, ReplayBuffer, TensorDictPrioritizedReplayBuffer, TensorDictReplayBuffer, TensorSpec
from torchrl.envs import EnvBase, ExplorationType, MultiStepTransform, TransformedEnv
from torchrl.envs.transforms import RNDTransform
from torchrl.modules import MLP, QValueActor, reset_noise
from torchrl.objectives import DQNLoss, HardUpdate, RNDLoss, SoftUpdate, TargetNetUpdater

from torchrl_mbe.app.config import is_planning
from torchrl_mbe.app.run import (
    GradientStep,
    Run,
    StopOnInterrupt,
    adam,
    evaluate_and_checkpoint_if_due,
    finish_run,
    open_run,
    record_frames,
)
from torchrl_mbe.envs import MountainCarDynamics, make_env
from torchrl_mbe.modules.dynamics import DynamicsModel
from torchrl_mbe.modules.exploration import AnnealedEGreedyModule, ModelBasedExplorationPolicy
from torchrl_mbe.modules.networks import make_per_action_mlp
from torchrl_mbe.modules.normalization import Standardize
from torchrl_mbe.modules.novelty import (
    DiagonalGaussianDensity,
    GaussianKernelNovelty,
    KernelDensityNovelty,
    KNearestNovelty,
    RollingGaussianDensity,
    RollingWindowNovelty,
)
from torchrl_mbe.modules.planner import NoveltyPlanner
from torchrl_mbe.objectives import DynamicsLoss

__all__ = ["DQNAgent", "build_dqn_agent", "make_replay_buffer", "ReplayTransitions", "train_dqn"]

log = logging.getLogger(__name__)

SUCCESSOR_KEY = "successor_observation"
"""The observation one step later, which the dynamics model learns (``("next", "observation")`` is n steps later)."""


def train_dqn(cfg: DictConfig, run_dir: Path) -> dict:
    """Trains DQN with the configured exploration and returns the run's summary."""
    env = make_env(cfg.env.name, seed=cfg.seed, num_envs=cfg.env.num_envs, device=cfg.device)
    agent = build_dqn_agent(cfg, env)
    replay_buffer = make_replay_buffer(cfg.buffer, cfg.device)
    run = open_run(cfg, run_dir, env, agent, replay_buffer)
    transitions = ReplayTransitions(cfg.algo.n_steps, cfg.algo.gamma, intrinsic_coef=agent.intrinsic_coef)
    collector = Collector(env, agent.policy, frames_per_batch=cfg.collector.frames_per_batch, total_frames=-1)
    batches = iter(collector)
    with StopOnInterrupt() as interrupt:
        while not (run.budget_spent() or interrupt.requested):
            batch = next(batches)
            stored = transitions(batch)
            if stored is not None:  # None while the first n-step windows fill
                replay_buffer.extend(stored)
            record_frames(run, batch)
            check_dynamics_on_new_data(agent, batch, run)
            learn_from_new_frames(agent, replay_buffer, batch.numel(), cfg.algo, cfg.dynamics, run)
            evaluate_and_checkpoint_if_due(run, batch.numel())
    collector.shutdown()
    return finish_run(run, interrupt)


@dataclass
class DQNAgent:
    """Everything a DQN run trains, saves and restores."""

    actor: QValueActor  # the greedy policy
    q_input_norm: Standardize | None  # fitted on the replay buffer before the first Q update
    policy: TensorDictModuleBase  # what the collector runs: the actor plus the exploration
    explorer: AnnealedEGreedyModule | None  # holds eps; its step() anneals it
    q_loss: DQNLoss
    target_updater: TargetNetUpdater
    q_step: GradientStep  # DQNLoss, clipping, Adam
    dynamics_loss: DynamicsLoss | None
    dynamics_step: GradientStep | None  # DynamicsLoss, clipping, Adam (None for the oracle)
    noisy: bool = False  # NoisyNet: the Q-network's noise is resampled after every Q step
    rnd: RNDTransform | None = None  # on the training env: writes ("next", "intrinsic_reward")
    rnd_loss: RNDLoss | None = None
    rnd_step: GradientStep | None = None  # RNDLoss on the Q step's batch, Adam
    intrinsic_coef: float | None = None  # the Q-network learns from reward + intrinsic_coef * intrinsic_reward

    @property
    def eps(self) -> float:
        """The exploration rate now (0 without an explorer)."""
        return float(self.explorer.eps) if self.explorer is not None else 0.0

    @property
    def novelty(self) -> RollingWindowNovelty | None:
        return self.explorer.novelty if isinstance(self.explorer, ModelBasedExplorationPolicy) else None

    def state_dict(self) -> dict:
        """The policy (Q-network, exploration, dynamics, window) once, the target network, the optimizers."""
        state = {
            "policy": self.policy.state_dict(),
            "target_network": self.q_loss.target_value_network_params.data.clone(),
            "target_updater_counter": getattr(self.target_updater, "counter", None),
            "q_optimizer": self.q_step.optimizer.state_dict(),
        }
        if self.dynamics_step is not None:
            state["dynamics_optimizer"] = self.dynamics_step.optimizer.state_dict()
        if self.rnd is not None:
            state["rnd"], state["rnd_optimizer"] = self.rnd.state_dict(), self.rnd_step.optimizer.state_dict()
        return state

    def load_state_dict(self, state: dict) -> None:
        self.policy.load_state_dict(state["policy"])
        self.q_loss.target_value_network_params.data.update_(state["target_network"])
        if state["target_updater_counter"] is not None:
            self.target_updater.counter = state["target_updater_counter"]
        self.q_step.optimizer.load_state_dict(state["q_optimizer"])
        if self.dynamics_step is not None:
            self.dynamics_step.optimizer.load_state_dict(state["dynamics_optimizer"])
        if self.rnd is not None:
            self.rnd.load_state_dict(state["rnd"])
            self.rnd_step.optimizer.load_state_dict(state["rnd_optimizer"])


def build_dqn_agent(cfg: DictConfig, env: TransformedEnv) -> DQNAgent:
    """The actor, the exploration policy, DQNLoss with its target updater, the dynamics loss and the optimizers.

    With ``exploration=rnd`` the RND transform is appended to ``env`` (the training env).
    """
    algo, exploration, device = cfg.algo, cfg.exploration, torch.device(cfg.device)
    action_spec = env.action_spec_unbatched.to(device)
    observation_size = env.observation_spec_unbatched["observation"].shape[-1]
    noise_std = exploration.std_init if exploration.name == "noisy" else None
    actor, q_input_norm = make_q_actor(
        observation_size, action_spec, algo.num_cells, device, standardize_inputs=algo.standardize_inputs, noise_std=noise_std
    )
    dynamics = make_dynamics(cfg, observation_size, action_spec, device) if is_planning(cfg) else None
    policy, explorer = make_exploration_policy(cfg, actor, dynamics, action_spec, observation_size, env.batch_size)
    q_loss = DQNLoss(actor, loss_function=algo.loss_function, double_dqn=algo.double_dqn, delay_value=True, action_space=action_spec)
    q_loss.make_value_estimator(gamma=algo.gamma)  # with n-step transitions it discounts by gamma ** steps_to_next_obs
    q_loss.in_keys  # DQNLoss resolves its input keys on first use: now, or a compiled step would be traced twice
    if noise_std is not None:  # a NoisyNet learns through its noise: the loss samples it, as the collector does
        q_loss.deterministic_sampling_mode = ExplorationType.RANDOM
    dynamics_loss = None
    if dynamics is not None:
        dynamics_loss = DynamicsLoss(dynamics)
        dynamics_loss.set_keys(next_observation=SUCCESSOR_KEY)
    dynamics_step = None
    if isinstance(dynamics, DynamicsModel):
        dynamics_optimizer = adam(dynamics.parameters(), cfg.dynamics.lr)
        dynamics_step = GradientStep(lambda batch: dynamics_loss(batch)["loss_dynamics"], dynamics_optimizer, cfg.dynamics.max_grad_norm, compile=cfg.compile)
    q_optimizer = adam(q_loss.parameters(), algo.lr)
    rnd, rnd_loss, rnd_step = make_rnd(exploration, env, observation_size, device, compile=cfg.compile) if exploration.name == "rnd" else (None,) * 3
    return DQNAgent(
        actor=actor,
        q_input_norm=q_input_norm,
        policy=policy,
        explorer=explorer,
        q_loss=q_loss,
        target_updater=make_target_updater(algo, q_loss),
        q_step=GradientStep(lambda batch: q_loss(batch)["loss"], q_optimizer, algo.max_grad_norm, compile=cfg.compile),
        dynamics_loss=dynamics_loss,
        dynamics_step=dynamics_step,
        noisy=noise_std is not None,
        rnd=rnd,
        rnd_loss=rnd_loss,
        rnd_step=rnd_step,
        intrinsic_coef=exploration.intrinsic_coef if rnd is not None else None,
    )


def make_rnd(
    exploration: DictConfig, env: TransformedEnv, observation_size: int, device: torch.device, *, compile: bool
) -> tuple[RNDTransform, RNDLoss, GradientStep]:
    """TorchRL's random network distillation: ``RNDTransform`` appended to ``env``, ``RNDLoss`` and its gradient step.

    The loss reads the transform's running observation statistics once they
    exist (after the first collected step; see :func:`update_rnd`).

    Examples:
        >>> import torch
        >>> from omegaconf import OmegaConf
        >>> from torchrl_mbe import make_env
        >>> from torchrl_mbe.app.config import RNDExploration
        >>> from torchrl_mbe.app.dqn import make_rnd
        >>> env = make_env("mountaincar", num_envs=4, seed=0)
        >>> rnd, loss, step = make_rnd(OmegaConf.structured(RNDExploration()), env, 2, torch.device("cpu"), compile=False)
        >>> env.rollout(3)["next", "intrinsic_reward"].shape
        torch.Size([4, 3, 1])
    """
    target, predictor = (
        MLP(in_features=observation_size, out_features=exploration.embedding_size, num_cells=list(exploration.num_cells), device=device)
        for _ in range(2)
    )
    rnd = RNDTransform(target, predictor)
    env.append_transform(rnd)
    loss = RNDLoss(predictor, target)
    optimizer = adam(predictor.parameters(), exploration.lr)
    return rnd, loss, GradientStep(lambda batch: loss(batch)["loss_predictor"], optimizer, None, compile=compile)


def make_q_actor(
    observation_size: int,
    action_spec: TensorSpec,
    num_cells,
    device: torch.device,
    *,
    standardize_inputs: bool,
    noise_std: float | None = None,
) -> tuple[QValueActor, Standardize | None]:
    """``QValueActor(MLP)`` with Glorot-uniform weights (the paper's Keras initialization).

    With ``standardize_inputs`` the MLP reads standardized observations; the
    returned :class:`~torchrl_mbe.modules.Standardize` is identity until the loop fits it.
    With ``noise_std`` the MLP is a NoisyNet (see :func:`~torchrl_mbe.modules.make_per_action_mlp`).
    """
    network = make_per_action_mlp(observation_size, action_spec, num_cells, device=device, noise_std=noise_std)
    if not standardize_inputs:
        return QValueActor(network, spec=action_spec, in_keys=["observation"]), None
    standardize = Standardize(observation_size, device=device)
    return QValueActor(nn.Sequential(standardize, network), spec=action_spec, in_keys=["observation"]), standardize


def make_dynamics(cfg: DictConfig, observation_size: int, action_spec: TensorSpec, device: torch.device) -> TensorDictModuleBase:
    """The dynamics model the planner uses: learned (``dynamics=mlp``) or MountainCar's physics (``oracle``)."""
    if cfg.dynamics.name == "oracle":
        return MountainCarDynamics(action_spec)
    return DynamicsModel(observation_size, action_spec, cfg.dynamics.num_cells, device=device)


def make_novelty(exploration: DictConfig, observation_size: int, batch_shape: torch.Size, device) -> RollingWindowNovelty:
    """The novelty scorer of ``exploration``, one window per environment."""
    kwargs = {"batch_shape": batch_shape, "device": device}
    if exploration.name == "gaussian":
        return RollingGaussianDensity(observation_size, exploration.window, **kwargs)
    if exploration.name == "diagonal":
        return DiagonalGaussianDensity(observation_size, exploration.window, **kwargs)
    if exploration.name == "knn":
        return KNearestNovelty(observation_size, exploration.window, k=exploration.k, **kwargs)
    if exploration.name == "kde":
        return KernelDensityNovelty(observation_size, exploration.window, **kwargs)
    return GaussianKernelNovelty(observation_size, exploration.window, bandwidth=exploration.bandwidth, **kwargs)


def make_exploration_policy(
    cfg: DictConfig,
    actor: QValueActor,
    dynamics: TensorDictModuleBase | None,
    action_spec: TensorSpec,
    observation_size: int,
    env_batch_size: torch.Size,
) -> tuple[TensorDictModuleBase, AnnealedEGreedyModule | None]:
    """What the collector runs (greedy ``actor`` plus the configured exploration) and its eps holder."""
    algo, exploration = cfg.algo, cfg.exploration
    schedule = {
        "eps_init": algo.eps_init,
        "eps_end": algo.eps_end,
        "annealing_num_steps": algo.eps_annealing_frames,
        "schedule": algo.eps_schedule,
    }
    if exploration.name in ("none", "noisy"):  # a NoisyNet explores through its own noise
        return actor, None
    if dynamics is None:  # egreedy, rnd
        egreedy = AnnealedEGreedyModule(action_spec, **schedule, device=action_spec.device)
        return TensorDictSequential(actor, egreedy), egreedy
    novelty = make_novelty(exploration, observation_size, env_batch_size, action_spec.device)
    planner = NoveltyPlanner(dynamics, novelty, action_spec, horizon=exploration.horizon)
    policy = ModelBasedExplorationPolicy(actor, planner, **schedule, model_error_threshold=exploration.model_error_threshold)
    return policy, policy


def make_target_updater(algo: DictConfig, q_loss: DQNLoss) -> TargetNetUpdater:
    """TorchRL's ``HardUpdate`` (copy every N updates) or ``SoftUpdate`` (Polyak)."""
    if algo.target_update == "hard":
        return HardUpdate(q_loss, value_network_update_interval=algo.hard_update_interval)
    return SoftUpdate(q_loss, tau=algo.soft_update_tau)


def make_replay_buffer(buffer: DictConfig, device: str) -> ReplayBuffer:
    """Uniform ``TensorDictReplayBuffer`` or ``TensorDictPrioritizedReplayBuffer`` (TD-error priorities).

    ``compilable=True`` keeps the buffer's counters in plain tensors instead of
    multiprocessing values: the buffer never leaves this process, and a killed
    run then leaves no semaphores behind.
    """
    storage = LazyTensorStorage(buffer.size, device=device, compilable=True)
    if buffer.name == "prioritized":
        return TensorDictPrioritizedReplayBuffer(
            alpha=buffer.alpha, beta=buffer.beta, storage=storage, priority_key="td_error", compilable=True
        )
    return TensorDictReplayBuffer(storage=storage, compilable=True)


class ReplayTransitions:
    """Turns collected frames into the transitions the losses read, and nothing more.

    With ``n_steps > 1``, TorchRL's :class:`~torchrl.envs.MultiStepTransform` sums
    the next ``n`` discounted rewards, points ``("next", "observation")`` ``n`` steps
    ahead and writes ``steps_to_next_obs`` (the DQN target then discounts by
    ``gamma ** steps_to_next_obs``). A window never crosses an episode's end; the
    ``terminated`` flag is taken from the window's last step (left out of the
    transform's pass-through ``done_keys``), so a window that ends in a time-limit
    truncation bootstraps and one that ends in a termination does not. The
    transform holds back the last ``n`` frames of each env until the next batch.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl_mbe.app.dqn import ReplayTransitions
        >>> flag = lambda *bits: torch.tensor(bits, dtype=torch.bool).unsqueeze(-1)
        >>> frames = TensorDict({  # 5 steps; the episode terminates at step 2
        ...     "observation": torch.arange(5.0).unsqueeze(-1), "action": torch.zeros(5, 1),
        ...     "next": {"observation": torch.arange(1.0, 6.0).unsqueeze(-1), "reward": torch.ones(5, 1),
        ...              "done": flag(0, 0, 1, 0, 0), "terminated": flag(0, 0, 1, 0, 0), "truncated": flag(0, 0, 0, 0, 0)},
        ... }, [5])
        >>> stored = ReplayTransitions(n_steps=3, gamma=0.5)(frames)  # the last 3 frames wait for the next batch
        >>> stored["next", "reward"].flatten().tolist(), stored["steps_to_next_obs"].flatten().tolist()
        ([1.75, 1.5], [3, 2])
        >>> stored["next", "observation"].flatten().tolist(), stored["next", "terminated"].flatten().tolist()
        ([3.0, 3.0], [True, True])
    """

    KEYS = ("observation", "action", ("next", "observation"), ("next", "reward"), ("next", "done"), ("next", "terminated"))

    def __init__(self, n_steps: int, gamma: float, *, intrinsic_coef: float | None = None) -> None:
        self.multistep = MultiStepTransform(n_steps, gamma, done_keys=["done", "truncated"]) if n_steps > 1 else None
        self.intrinsic_coef = intrinsic_coef

    def __call__(self, frames: TensorDictBase) -> TensorDictBase | None:
        """Transitions of ``frames`` (``(time,)`` or ``(envs, time)``) as a flat batch; ``None`` while held back.

        With ``intrinsic_coef``, the stored reward is ``reward + intrinsic_coef * ("next", "intrinsic_reward")``.
        """
        transitions = one_step_transitions(frames)
        if self.intrinsic_coef is not None:
            reward = frames.get(("next", "reward")) + self.intrinsic_coef * frames.get(("next", "intrinsic_reward"))
            transitions.set(("next", "reward"), reward)
        frames = transitions
        if self.multistep is not None:
            frames = self.multistep.inv(frames)
            if frames is None:
                return None
            frames = frames.exclude("gamma", "nonterminal", ("next", "original_reward"))
        return frames.reshape(-1)


def one_step_transitions(frames: TensorDictBase) -> TensorDictBase:
    """The keys the losses read from collected ``frames``, with the one-step successor the dynamics model learns."""
    transitions = frames.select(*ReplayTransitions.KEYS)
    return transitions.set(SUCCESSOR_KEY, transitions.get(("next", "observation")))


def check_dynamics_on_new_data(agent: DQNAgent, batch: TensorDictBase, run: Run) -> None:
    """Dynamics error on freshly collected transitions (not yet trained on); feeds the warm-up switch."""
    if agent.dynamics_loss is None:
        return
    progress = run.progress
    frames = one_step_transitions(batch).reshape(-1)
    with torch.no_grad():
        error = float(agent.dynamics_loss(frames)["loss_dynamics"])
    previous = progress.dynamics_val_error
    progress.dynamics_val_error = error if previous is None else 0.9 * previous + 0.1 * error
    agent.explorer.report_model_error(progress.dynamics_val_error)


def learn_from_new_frames(
    agent: DQNAgent, replay_buffer: ReplayBuffer, new_frames: int, algo: DictConfig, dynamics: DictConfig, run: Run
) -> None:
    """The updates that ``new_frames`` frames pay for: dynamics steps, Q steps with target updates, eps decay."""
    progress = run.progress
    frames = progress.frames
    if agent.dynamics_step is not None and frames >= dynamics.learning_starts:
        progress.dynamics_update_credit += new_frames * dynamics.updates_per_frame
        while progress.dynamics_update_credit >= 1:
            if progress.dynamics_updates == 0:
                agent.dynamics_loss.dynamics.fit_normalization(replay_buffer, next_observation_key=SUCCESSOR_KEY)
            progress.last_loss_dynamics = update_dynamics(agent, replay_buffer, dynamics.batch_size)
            progress.dynamics_updates += 1
            progress.dynamics_update_credit -= 1
    if frames < algo.learning_starts:
        return
    if agent.explorer is not None:
        agent.explorer.step(min(new_frames, frames - algo.learning_starts))
    for group in agent.q_step.optimizer.param_groups:
        group["lr"] = q_learning_rate(algo, frames)
    progress.q_update_credit += new_frames * algo.updates_per_frame
    batch_size, log_every = algo.batch_size, run.cfg.logger.log_every_updates  # read once: a config lookup costs ~10 us
    while progress.q_update_credit >= 1:
        if progress.q_updates == 0 and agent.q_input_norm is not None:
            fit_q_input_norm(agent, replay_buffer)
        losses = update_q(agent, replay_buffer, batch_size)
        progress.q_updates += 1
        progress.q_update_credit -= 1
        if log_every and progress.q_updates % log_every == 0:
            log_updates(losses, agent, run)


def q_learning_rate(algo: DictConfig, frames: int) -> float:
    """``algo.lr``, decayed linearly to ``lr * lr_end_factor`` over ``lr_decay_frames`` frames after ``learning_starts``.

    A function of the frame count, so a resumed run continues the same schedule.
    """
    if algo.lr_decay_frames is None:
        return algo.lr
    done = min(max(frames - algo.learning_starts, 0) / algo.lr_decay_frames, 1.0)
    return algo.lr * (1.0 - done * (1.0 - algo.lr_end_factor))


@torch.no_grad()
def fit_q_input_norm(agent: DQNAgent, replay_buffer: ReplayBuffer) -> None:
    """Fits the Q-network's input statistics once, on what the buffer holds, and gives them to the target network.

    Target updaters copy parameters, not buffers; the statistics never change
    after this fit, so copying them here keeps both networks consistent.
    """
    agent.q_input_norm.fit(replay_buffer[: len(replay_buffer)]["observation"])
    agent.q_loss.target_value_network_params.update_(agent.q_loss.value_network_params)


def update_q(agent: DQNAgent, replay_buffer: ReplayBuffer, batch_size: int) -> dict[str, float]:
    """One DQN gradient step (TorchRL's DQNLoss) and a target-network update; the RND predictor learns on the same batch.

    Returns the losses: ``loss_q``, and ``loss_rnd`` (the predictor's) with RND.
    """
    sample = replay_buffer.sample(batch_size)
    batch = sample.exclude("index")  # the same keys at every call, so a compiled step is traced once
    losses = {"loss_q": agent.q_step(batch)}
    agent.target_updater.step()
    if agent.noisy:
        agent.actor.apply(reset_noise)
    if agent.rnd is not None:
        losses["loss_rnd"] = update_rnd(agent, batch)
    if isinstance(replay_buffer, TensorDictPrioritizedReplayBuffer):
        sample.set("td_error", batch.get("td_error"))
        replay_buffer.update_tensordict_priority(sample)
    return losses


def update_rnd(agent: DQNAgent, batch: TensorDictBase) -> float:
    """One step of the RND predictor, normalizing observations with the statistics the transform collects with."""
    if agent.rnd_loss.obs_rms is None:  # the transform creates them at its first step
        agent.rnd_loss.obs_rms = agent.rnd.obs_rms
    return agent.rnd_step(batch)


def update_dynamics(agent: DQNAgent, replay_buffer: ReplayBuffer, batch_size: int) -> float:
    """One gradient step of the dynamics model on its own batch from the same buffer."""
    return agent.dynamics_step(replay_buffer.sample(batch_size).exclude("index"))


def log_updates(losses: dict[str, float], agent: DQNAgent, run: Run) -> None:
    progress = run.progress
    run.logger.log(
        "updates",
        {
            "frames": progress.frames,
            "updates": progress.q_updates,
            **losses,
            "loss_dynamics": progress.last_loss_dynamics,
            "dynamics_val_error": progress.dynamics_val_error,
            "eps": agent.eps,
            "frames_per_s": progress.frames / max(progress.wall_time_s, 1e-9),
        },
    )
