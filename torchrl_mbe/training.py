"""The training app's loop: DQN with model-based exploration (Algorithm 1), top to bottom.

``train(cfg)`` takes a composed Hydra config (``conf/``) and returns a summary;
``train.py`` at the repository root is the thin ``@hydra.main`` wrapper.
``algo=reinforce`` runs the paper's policy-gradient baseline instead
(:func:`torchrl_mbe.reinforce.train_reinforce`), which reuses this module's
logging, evaluation, checkpoint and interrupt handling.
"""
from __future__ import annotations

import json
import logging
import signal
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf
from tensordict import TensorDictBase
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, ReplayBuffer, TensorDictPrioritizedReplayBuffer, TensorDictReplayBuffer
from torchrl.envs import EnvBase, ExplorationType, set_exploration_type
from tqdm.auto import tqdm

from torchrl_mbe.agent import Agent, build_agent, method_name
from torchrl_mbe.config import ConfigError, check_config, config_differences
from torchrl_mbe.envs import SOLVED_THRESHOLDS, make_env, resolve_env_id
from torchrl_mbe.episodes import finished_episodes, reached_goal
from torchrl_mbe.run_logger import RunLogger

if TYPE_CHECKING:
    from torchrl_mbe.reinforce import ReinforceAgent

__all__ = ["train", "evaluate", "CHECKPOINT_NAME"]

log = logging.getLogger(__name__)
CHECKPOINT_NAME = "checkpoint.pt"


@dataclass
class Progress:
    """Counters that a checkpoint restores."""

    frames: int = 0
    episodes: int = 0
    q_updates: int = 0
    dynamics_updates: int = 0
    q_update_credit: float = 0.0
    dynamics_update_credit: float = 0.0
    first_success_episode: int | None = None
    wall_time_s: float = 0.0
    dynamics_val_error: float | None = None
    last_loss_dynamics: float | None = None
    visited: list = field(default_factory=list)  # (observations, episode ids) per batch, if recorded


@dataclass
class Run:
    """One training run's parts: its config, environments, agent, memory, counters and logs."""

    cfg: DictConfig
    run_dir: Path
    env_id: str
    env: EnvBase
    eval_env: EnvBase
    agent: Agent | ReinforceAgent
    buffer: ReplayBuffer | None
    progress: Progress
    logger: RunLogger


def open_run(cfg: DictConfig, run_dir: Path, build, *, replay_buffer: bool) -> Run:
    """Builds the environments and ``build(cfg, env)``'s agent, then starts or resumes the run.

    Any value the parts reject becomes a :class:`~torchrl_mbe.config.ConfigError`.
    """
    try:
        env_id = resolve_env_id(cfg.env.name)
        env = make_env(cfg.env.name, seed=cfg.seed, num_envs=cfg.env.num_envs, device=cfg.device)
        eval_env = make_env(cfg.env.name, seed=cfg.seed + 10_000, device=cfg.device)
        agent = build(cfg, env)
        buffer = make_replay_buffer(cfg.buffer, cfg.device) if replay_buffer else None
    except (ValueError, TypeError) as error:
        raise ConfigError(str(error)) from error
    progress = start_or_resume(cfg, run_dir, agent, buffer)
    logger = RunLogger(run_dir, cfg, resume_frames=progress.frames if cfg.resume else None)
    return Run(cfg, run_dir, env_id, env, eval_env, agent, buffer, progress, logger)


def train(cfg: DictConfig, run_dir: str | Path | None = None) -> dict:
    """Trains DQN (or, with ``algo=reinforce``, REINFORCE) and returns the run's summary.

    Args:
        cfg (DictConfig): a config composed from ``conf/`` (see ``docs/usage.md``).
        run_dir (path, optional): where CSVs, checkpoints and the summary go;
            defaults to Hydra's output directory.
    """
    run_dir = Path(run_dir) if run_dir is not None else Path(_hydra_output_dir())
    check_config(cfg)
    if cfg.torch_threads:
        torch.set_num_threads(cfg.torch_threads)
    torch.manual_seed(cfg.seed)
    if cfg.algo.name == "reinforce":
        from torchrl_mbe.reinforce import train_reinforce  # here: reinforce builds on this module

        return train_reinforce(cfg, run_dir)
    run = open_run(cfg, run_dir, build_agent, replay_buffer=True)
    agent, buffer, progress = run.agent, run.buffer, run.progress
    collector = Collector(run.env, agent.policy, frames_per_batch=cfg.collector.frames_per_batch, total_frames=-1)
    bar = tqdm(total=cfg.train.episodes, initial=progress.episodes, unit="ep", disable=not cfg.progress_bar)
    started = time.perf_counter() - progress.wall_time_s
    with StopOnInterrupt() as interrupt:
        for batch in collector:
            buffer.extend(batch.reshape(-1))
            progress.frames += batch.numel()
            progress.wall_time_s = time.perf_counter() - started
            record_episodes(batch, run.env_id, agent.eps, progress, run.logger, bar)
            if cfg.train.save_visited_states:
                record_visited_states(batch, progress)
            check_dynamics_on_new_data(batch, agent, progress)
            train_on_new_frames(cfg, batch.numel(), agent, buffer, progress, run.logger)
            evaluate_and_checkpoint_if_due(run, batch.numel())
            if budget_spent(cfg, progress) or interrupt.requested:
                break
    collector.shutdown()
    bar.close()
    return finish_run(run, interrupted=interrupt.requested)


class StopOnInterrupt:
    """Turns the first Ctrl-C (SIGINT) into a request to stop after the current batch.

    The loop then saves a consistent checkpoint (every counted frame is in the
    replay buffer) before exiting; a second Ctrl-C interrupts at once.
    """

    def __enter__(self) -> StopOnInterrupt:
        self.requested = False
        self._previous = signal.getsignal(signal.SIGINT)
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGINT, self._request_stop)
        return self

    def _request_stop(self, signum, frame) -> None:
        self.requested = True
        signal.signal(signal.SIGINT, self._previous)
        log.warning("Ctrl-C: stopping after this batch and saving a checkpoint (Ctrl-C again to abort now).")

    def __exit__(self, *exc_info) -> None:
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGINT, self._previous)


def make_replay_buffer(buffer_cfg: DictConfig, device: str) -> ReplayBuffer:
    """Uniform ``TensorDictReplayBuffer`` or ``TensorDictPrioritizedReplayBuffer`` (TD-error priorities)."""
    storage = LazyTensorStorage(buffer_cfg.size, device=device)
    if buffer_cfg.name == "uniform":
        return TensorDictReplayBuffer(storage=storage)
    if buffer_cfg.name == "prioritized":
        return TensorDictPrioritizedReplayBuffer(
            alpha=buffer_cfg.alpha, beta=buffer_cfg.beta, storage=storage, priority_key="td_error"
        )
    raise ValueError(f"buffer.name must be 'uniform' or 'prioritized', got {buffer_cfg.name!r}.")


def start_or_resume(cfg: DictConfig, run_dir: Path, agent: Agent | ReinforceAgent, buffer: ReplayBuffer | None) -> Progress:
    """Fresh counters, or the last checkpoint's state when ``cfg.resume`` is set (``buffer=None``: no replay buffer)."""
    checkpoint_path = run_dir / CHECKPOINT_NAME
    if not cfg.resume:
        if checkpoint_path.exists():
            raise ConfigError(
                f"{run_dir} already holds a run. Pass resume=true to continue it, "
                "or choose another directory (hydra.run.dir=... or another tag/seed)."
            )
        return Progress()
    if not checkpoint_path.exists():
        raise ConfigError(f"resume=true but {checkpoint_path} does not exist: nothing to resume.")
    try:
        checkpoint = torch.load(checkpoint_path, weights_only=False)
    except Exception as error:  # a truncated or foreign file: say which, keep it
        raise ConfigError(f"Cannot read checkpoint {checkpoint_path}: {error}") from error
    differences = config_differences(checkpoint["config"], cfg)
    if differences:
        raise ConfigError(
            f"The checkpoint in {run_dir} was made with another config; differing keys: " + "; ".join(differences)
        )
    agent.load_state_dict(checkpoint["agent"])
    if buffer is not None:
        buffer.load_state_dict(checkpoint["buffer"])
    torch.set_rng_state(checkpoint["torch_rng"])
    log.info("Resumed %s at %d frames, %d episodes", run_dir, checkpoint["progress"]["frames"], checkpoint["progress"]["episodes"])
    return Progress(**checkpoint["progress"])


def record_episodes(batch: TensorDictBase, env_id: str, eps: float, progress: Progress, logger: RunLogger, bar) -> None:
    """Logs every episode that ended in ``batch`` (``eps``: the exploration rate that acted) and advances the progress bar."""
    for episode in finished_episodes(batch):
        progress.episodes += 1
        success = reached_goal(env_id, episode)
        if success and progress.first_success_episode is None:
            progress.first_success_episode = progress.episodes
        logger.log(
            "episodes",
            {
                "episode": progress.episodes,
                "frames": progress.frames,
                "return": episode.episode_return,
                "length": episode.length,
                "reached_goal": int(success),
                "eps": round(eps, 5),
                "wall_time_s": round(progress.wall_time_s, 3),
            },
        )
        bar.update(1)
        bar.set_postfix(frames=progress.frames, ret=f"{episode.episode_return:.0f}", eps=f"{eps:.3f}")


def record_visited_states(batch: TensorDictBase, progress: Progress) -> None:
    """Keeps every state the agent arrived in (``("next", "observation")``, so goal states count) with its 1-based episode."""
    steps = batch.transpose(0, 1) if batch.ndim == 2 else batch
    steps = steps.reshape(-1)
    done = steps["next", "done"].reshape(-1).long()
    ended_before = progress.episodes - int(done.sum())
    episode_ids = ended_before + 1 + torch.cumsum(done, 0) - done
    progress.visited.append((steps["next", "observation"].cpu(), episode_ids.cpu()))


def check_dynamics_on_new_data(batch: TensorDictBase, agent: Agent, progress: Progress) -> None:
    """Dynamics error on freshly collected transitions (not yet trained on); feeds the warm-up switch."""
    if agent.dynamics_loss is None:
        return
    with torch.no_grad():
        error = float(agent.dynamics_loss(batch.reshape(-1))["loss_dynamics"])
    previous = progress.dynamics_val_error
    progress.dynamics_val_error = error if previous is None else 0.9 * previous + 0.1 * error
    agent.explorer.report_model_error(progress.dynamics_val_error)


def train_on_new_frames(cfg: DictConfig, new_frames: int, agent: Agent, buffer: ReplayBuffer, progress: Progress, logger: RunLogger) -> None:
    """The updates that ``new_frames`` frames pay for: dynamics steps, Q steps, target updates, eps decay."""
    if agent.dynamics_optimizer is not None and progress.frames >= cfg.dynamics.learning_starts:
        progress.dynamics_update_credit += new_frames * cfg.dynamics.updates_per_frame
        while progress.dynamics_update_credit >= 1:
            if progress.dynamics_updates == 0:
                agent.dynamics.fit_normalization(buffer)
            progress.last_loss_dynamics = update_dynamics(agent, buffer, cfg.dynamics.batch_size, cfg.algo.max_grad_norm)
            progress.dynamics_updates += 1
            progress.dynamics_update_credit -= 1
    if progress.frames < cfg.algo.learning_starts:
        return
    if agent.explorer is not None:
        agent.explorer.step(min(new_frames, progress.frames - cfg.algo.learning_starts))
    progress.q_update_credit += new_frames * cfg.algo.updates_per_frame
    while progress.q_update_credit >= 1:
        if progress.q_updates == 0 and agent.q_input_norm is not None:
            fit_q_input_norm(agent, buffer)
        loss_q = update_q(agent, buffer, cfg.algo.batch_size, cfg.algo.max_grad_norm)
        progress.q_updates += 1
        progress.q_update_credit -= 1
        if cfg.logger.log_every_updates and progress.q_updates % cfg.logger.log_every_updates == 0:
            log_updates(loss_q, agent, progress, logger)


@torch.no_grad()
def fit_q_input_norm(agent: Agent, buffer: ReplayBuffer) -> None:
    """Fits the Q-network's input statistics once, on what the buffer holds, and gives them to the target network.

    Target updaters copy parameters, not buffers; the statistics never change
    after this fit, so copying them here keeps both networks consistent.
    """
    agent.q_input_norm.fit(buffer[: len(buffer)]["observation"])
    agent.q_loss.target_value_network_params.update_(agent.q_loss.value_network_params)


def update_q(agent: Agent, buffer: ReplayBuffer, batch_size: int, max_grad_norm: float | None) -> float:
    """One DQN gradient step (TorchRL's DQNLoss) and a target-network update."""
    sample = buffer.sample(batch_size)
    loss = agent.q_loss(sample)["loss"]
    optimizer_step(loss, agent.q_optimizer, max_grad_norm)
    agent.target_updater.step()
    if isinstance(buffer, TensorDictPrioritizedReplayBuffer):
        buffer.update_tensordict_priority(sample)
    return loss.item()


def update_dynamics(agent: Agent, buffer: ReplayBuffer, batch_size: int, max_grad_norm: float | None) -> float:
    """One gradient step of the dynamics model on its own batch from the same buffer."""
    loss = agent.dynamics_loss(buffer.sample(batch_size))["loss_dynamics"]
    optimizer_step(loss, agent.dynamics_optimizer, max_grad_norm)
    return loss.item()


def optimizer_step(loss: torch.Tensor, optimizer: torch.optim.Optimizer, max_grad_norm: float | None) -> None:
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    if max_grad_norm is not None:
        for group in optimizer.param_groups:
            torch.nn.utils.clip_grad_norm_(group["params"], max_grad_norm)
    optimizer.step()


def evaluate(actor, env: EnvBase, episodes: int, env_id: str) -> dict:
    """Greedy (``ExplorationType.DETERMINISTIC``) returns over ``episodes`` episodes."""
    returns, successes = [], []
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        for _ in range(episodes):
            episode = finished_episodes(play_episode(env, actor))[-1]
            returns.append(episode.episode_return)
            successes.append(reached_goal(env_id, episode))
    return {
        "eval_return_mean": float(np.mean(returns)),
        "eval_return_std": float(np.std(returns)),
        "eval_success_rate": float(np.mean(successes)),
    }


def play_episode(env: EnvBase, policy) -> TensorDictBase:
    """One whole episode of ``policy`` in a single ``env``, shape ``(steps,)``, under the caller's exploration type."""
    return env.rollout(max_steps=100_000, policy=policy, break_when_any_done=True)


def log_evaluation(result: dict, progress: Progress, logger: RunLogger) -> None:
    logger.log("evaluations", {"frames": progress.frames, "episode": progress.episodes, **result})
    log.info("eval at %d frames: return %.1f", progress.frames, result["eval_return_mean"])


def log_updates(loss_q: float, agent: Agent, progress: Progress, logger: RunLogger) -> None:
    logger.log(
        "updates",
        {
            "frames": progress.frames,
            "updates": progress.q_updates,
            "loss_q": loss_q,
            "loss_dynamics": progress.last_loss_dynamics,
            "dynamics_val_error": progress.dynamics_val_error,
            "eps": agent.eps,
            "frames_per_s": progress.frames / max(progress.wall_time_s, 1e-9),
        },
    )


def budget_spent(cfg: DictConfig, progress: Progress) -> bool:
    max_frames = cfg.train.max_frames
    return progress.episodes >= cfg.train.episodes or (max_frames is not None and progress.frames >= max_frames)


def save_checkpoint(run: Run) -> None:
    """Writes the checkpoint atomically (a crash mid-write keeps the previous one)."""
    checkpoint = {
        "config": OmegaConf.to_container(run.cfg, resolve=True),
        "agent": run.agent.state_dict(),
        "buffer": run.buffer.state_dict() if run.buffer is not None else None,
        "progress": asdict(run.progress),
        "torch_rng": torch.get_rng_state(),
    }
    partial = run.run_dir / (CHECKPOINT_NAME + ".partial")
    torch.save(checkpoint, partial)
    partial.replace(run.run_dir / CHECKPOINT_NAME)


def evaluate_and_checkpoint_if_due(run: Run, new_frames: int) -> None:
    """The periodic greedy evaluation and checkpoint, when the last ``new_frames`` frames crossed their period."""
    frames, cfg = run.progress.frames, run.cfg
    if _crossed(frames, new_frames, cfg.eval.every_frames) and cfg.eval.episodes:
        log_evaluation(evaluate(run.agent.actor, run.eval_env, cfg.eval.episodes, run.env_id), run.progress, run.logger)
    if _crossed(frames, new_frames, cfg.train.checkpoint_every_frames):
        save_checkpoint(run)


def finish_run(run: Run, *, interrupted: bool) -> dict:
    """Saves the last checkpoint; unless ``interrupted`` (then it exits), evaluates greedily and writes the summary."""
    save_checkpoint(run)
    if interrupted:
        run.logger.close()
        raise SystemExit(
            f"Interrupted at {run.progress.frames} frames; checkpoint saved in {run.run_dir}. Continue with resume=true."
        )
    episodes = run.cfg.eval.final_episodes
    final = evaluate(run.agent.actor, run.eval_env, episodes, run.env_id) if episodes else None
    if final is not None:
        log_evaluation(final, run.progress, run.logger)
    run.logger.close()
    return write_summary(run.run_dir, run.cfg, run.env_id, run.progress, final)


def write_summary(run_dir: Path, cfg: DictConfig, env_id: str, progress: Progress, final: dict | None) -> dict:
    """``summary.json`` (what the report groups runs by) and visited states, if recorded."""
    summary = {
        "env": env_id,
        "method": method_name(cfg),
        "seed": cfg.seed,
        "frames": progress.frames,
        "episodes": progress.episodes,
        "q_updates": progress.q_updates,
        "dynamics_updates": progress.dynamics_updates,
        "wall_time_s": round(progress.wall_time_s, 2),
        "frames_per_s": round(progress.frames / max(progress.wall_time_s, 1e-9), 1),
        "first_success_episode": progress.first_success_episode,
        "final_eval_return": final["eval_return_mean"] if final else None,
        "final_eval_success_rate": final["eval_success_rate"] if final else None,
        "solved_threshold": SOLVED_THRESHOLDS.get(env_id),
    }
    (run_dir / "summary.json").write_text(json.dumps(summary, indent=2))
    if progress.visited:
        observations, episode_ids = map(torch.cat, zip(*progress.visited))
        np.save(run_dir / "visited_states.npy", observations.numpy().astype(np.float32))
        np.save(run_dir / "visited_episodes.npy", episode_ids.numpy())
    return summary


def _crossed(frames: int, new_frames: int, every: int) -> bool:
    """Whether the last ``new_frames`` frames crossed a multiple of ``every``."""
    return frames // every > (frames - new_frames) // every


def _hydra_output_dir() -> str:
    from hydra.core.hydra_config import HydraConfig

    return HydraConfig.get().runtime.output_dir
