"""A training run's life, shared by every algorithm's loop: open or resume, record, evaluate, checkpoint, finish.

An algorithm's loop (:mod:`torchrl_mbe.app.dqn`, :mod:`torchrl_mbe.app.reinforce`)
builds its agent, calls :func:`open_run`, and for every batch of frames calls
:func:`record_frames` (counters, episode log), learns, then calls
:func:`evaluate_and_checkpoint_if_due` (periodic greedy evaluation, best policy,
checkpoint); it ends with :func:`finish_run`. The files
it writes are those of :mod:`torchrl_mbe.rundir`.
"""

from __future__ import annotations

import json
import logging
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.envs import EnvBase
from tqdm.auto import tqdm

from torchrl_mbe.app.checkpoints import (
    CHECKPOINT_FORMAT,
    read_checkpoint,
    refuse_to_overwrite,
    save_atomically,
)
from torchrl_mbe.app.config import config_id, method_name, with_size
from torchrl_mbe.app.evaluation import evaluate
from torchrl_mbe.app.explorers import logged_counters
from torchrl_mbe.app.loggers import RunLogger
from torchrl_mbe.app.observation import env_options
from torchrl_mbe.app.rollout import EnvState
from torchrl_mbe.envs import (
    finished_episodes,
    make_env,
    reached_goal,
    resolve_env_id,
)
from torchrl_mbe.envs.registry import SolvedRule, solved_rule
from torchrl_mbe.rundir import BEST_POLICY, CHECKPOINT, SUMMARY, UPDATE_COUNTERS, VISITED_EPISODES, VISITED_STATES

__all__ = [
    "Agent",
    "Progress",
    "Resumable",
    "Run",
    "RunFinished",
    "StopOnInterrupt",
    "budget_spent",
    "close_run",
    "confirmed_now",
    "crossed",
    "evaluate_and_checkpoint_if_due",
    "finish_run",
    "keep_in_checkpoints",
    "log_evaluation",
    "make_run_env",
    "note_evaluation",
    "open_run",
    "record_frames",
    "record_updates",
]

log = logging.getLogger(__name__)
tqdm.set_lock(threading.RLock())  # tqdm's default lock is a multiprocessing semaphore, left behind by a killed run


class Resumable(Protocol):
    """Anything whose state a checkpoint keeps."""

    def state_dict(self) -> dict: ...

    def load_state_dict(self, state: dict) -> None: ...


class Agent(Protocol):
    """What the run needs of an algorithm's agent."""

    actor: TensorDictModuleBase  # the greedy actor (evaluation, best policy)

    def summary_fields(
        self,
    ) -> dict[str, int]: ...  # its update counters (rundir.UPDATE_COUNTERS, its explorer's counters)

    def state_dict(self) -> dict: ...  # everything it trains and counts

    def load_state_dict(self, state: dict) -> None: ...


class RunFinished(Exception):
    """``resume=true`` on a run that already spent its budget: nothing to do; carries its summary."""

    def __init__(self, summary: dict) -> None:
        super().__init__("finished")
        self.summary = summary


@dataclass
class Progress:
    """The run's counters, shared by every algorithm, that a checkpoint restores (an agent keeps its own)."""

    frames: int = 0
    episodes: int = 0
    first_success_episode: int | None = None
    wall_time_s: float = 0.0
    best_eval_return: float | None = None
    best_eval_frames: int | None = None
    solved_at_frames: int | None = None
    solved_at_wall_time_s: float | None = None


@dataclass
class Run:
    """One training run's parts: its config, environments, agent, memory, counters and logs."""

    cfg: DictConfig
    run_dir: Path
    env_id: str
    eval_env: EnvBase  # ``eval.episodes`` copies: one periodic evaluation is one batched rollout
    agent: Agent
    progress: Progress
    logger: RunLogger
    bar: tqdm
    started: float = field(default_factory=time.perf_counter)
    confirmation: tuple[int, dict] | None = None  # (frames, result) of the evaluation that confirmed "solved"
    visited: list = field(default_factory=list)  # (observations, episode ids) per batch, with train.save_visited_states
    kept: dict[str, Resumable] = field(default_factory=dict)  # the loop's parts whose state checkpoints keep
    resumed: dict | None = None  # their states in the checkpoint this run resumed from

    @property
    def solved_rule(self) -> SolvedRule | None:
        return solved_rule(self.env_id)

    def budget_spent(self) -> bool:
        """Whether the training budget is used up (or the task solved, with ``train.stop_when_solved``)."""
        return budget_spent(self.cfg.train, self.progress)


def budget_spent(train: DictConfig, progress: Progress) -> bool:
    """Whether ``progress`` has used up the budget of ``train`` (or solved the task, with ``train.stop_when_solved``)."""
    if train.stop_when_solved and progress.solved_at_frames is not None:
        return True
    return progress.episodes >= train.episodes or (train.max_frames is not None and progress.frames >= train.max_frames)


def open_run(cfg: DictConfig, run_dir: Path, agent: Agent) -> Run:
    """Starts the run in ``run_dir``, or resumes it from its checkpoint with ``cfg.resume``.

    The loop then names the other parts whose state checkpoints keep
    (:func:`keep_in_checkpoints`: the replay buffer, the collector, ...).

    Raises:
        ConfigError: ``run_dir`` holds a run and ``resume`` is off; nothing to
            resume; an unreadable checkpoint or one of another config or version.
        RunFinished: ``resume`` on a run that already spent its (new) budget.
    """
    env_id = resolve_env_id(cfg.env.name)
    eval_env = make_run_env(cfg, num_envs=max(cfg.eval.episodes, 1), seed=cfg.seed + 10_000)
    if not cfg.resume:
        refuse_to_overwrite(run_dir)
    checkpoint = read_checkpoint(cfg, run_dir) if cfg.resume else None
    progress = _restore(checkpoint, agent) if checkpoint is not None else Progress()
    logger = RunLogger(run_dir, cfg, resume_frames=progress.frames if cfg.resume else None)
    bar = _progress_bar(cfg, progress)
    run = Run(cfg, run_dir, env_id, eval_env, agent, progress, logger, bar)
    if checkpoint is not None:
        run.resumed = checkpoint["kept"]
        run.visited = checkpoint["visited"] or []
    keep_in_checkpoints(run, "eval_env", EnvState(eval_env))  # its start states go on where they stopped
    run.started -= progress.wall_time_s
    summary = _summary_of_this_checkpoint(run_dir, progress) if cfg.resume else None
    if summary is not None and run.budget_spent():
        logger.close()
        raise RunFinished(summary)
    log.info("Run directory: %s", run_dir)
    return run


def make_run_env(cfg: DictConfig, *, num_envs: int, seed: int) -> EnvBase:
    """The configured env (``cfg.env``, on ``cfg.device``): training, evaluation and final envs are the same task.

    With ``population=M > 1`` the batch is ``(num_envs, M)``: ``num_envs`` copies per member.
    """
    batch = num_envs if cfg.population == 1 else (num_envs, cfg.population)
    return make_env(cfg.env.name, num_envs=batch, seed=seed, device=cfg.device, **env_options(cfg.env))


def _summary_of_this_checkpoint(run_dir: Path, progress: Progress) -> dict | None:
    """The run's summary if it was written at the checkpoint's frame count (the run finished there), else ``None``."""
    path = run_dir / SUMMARY
    if not path.exists():
        return None
    summary = json.loads(path.read_text())
    return summary if summary.get("frames") == progress.frames else None


def _progress_bar(cfg: DictConfig, progress: Progress) -> tqdm:
    """Counts frames when the budget is in frames (``train.max_frames``), else episodes; off when not a terminal."""
    frames_budget = cfg.train.max_frames is not None
    return tqdm(
        total=cfg.train.max_frames if frames_budget else cfg.train.episodes,
        initial=progress.frames if frames_budget else progress.episodes,
        unit="frame" if frames_budget else "ep",
        unit_scale=frames_budget,
        disable=None if cfg.progress_bar else True,
    )


def _restore(checkpoint: dict, agent: Agent) -> Progress:
    agent.load_state_dict(checkpoint["agent"])
    torch.set_rng_state(checkpoint["torch_rng"])
    progress = Progress(**checkpoint["progress"])
    log.info("Resumed at %d frames, %d episodes", progress.frames, progress.episodes)
    return progress


def keep_in_checkpoints(run: Run, name: str, part: Resumable) -> None:
    """Puts ``part``'s state into every checkpoint from now on; a resumed run restores it here, from its checkpoint."""
    run.kept[name] = part
    if run.resumed is not None:
        part.load_state_dict(run.resumed[name])


class StopOnInterrupt:
    """Turns the first Ctrl-C (SIGINT) into a request to stop at the next safe point.

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
        log.warning("Ctrl-C: stopping at the next safe point and saving a checkpoint (Ctrl-C again to abort now).")

    def __exit__(self, *exc_info) -> None:
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGINT, self._previous)


def record_frames(run: Run, batch: TensorDictBase, *, eps: float = 0.0) -> None:
    """Counts the collected ``batch`` (``(time,)`` or ``(envs, time)``), logs the episodes that ended in it
    (with ``eps``, the exploration rate that acted) and records visited states if asked."""
    progress = run.progress
    progress.frames += batch.numel()
    progress.wall_time_s = time.perf_counter() - run.started
    if run.cfg.train.max_frames is not None:  # the bar counts frames (see _progress_bar)
        run.bar.update(batch.numel())
    _record_episodes(run, batch, eps)
    if run.cfg.train.save_visited_states:
        run.visited.append(_visited_states(batch, progress))


def record_updates(run: Run, rows: list[dict]) -> None:
    """Logs rows of the updates table, each with the throughput so far."""
    progress = run.progress
    for row in rows:
        run.logger.log("updates", {**row, "frames_per_s": progress.frames / max(progress.wall_time_s, 1e-9)})


def evaluate_and_checkpoint_if_due(run: Run, new_frames: int) -> None:
    """The periodic greedy evaluation (keeping the best policy) and checkpoint, when the last ``new_frames`` crossed their period."""
    frames, cfg = run.progress.frames, run.cfg
    if crossed(frames, new_frames, cfg.eval.every_frames) and cfg.eval.episodes:
        _periodic_evaluation(run)
    if crossed(frames, new_frames, cfg.train.checkpoint_every_frames):
        save_checkpoint(run)


def _record_episodes(run: Run, batch: TensorDictBase, eps: float) -> None:
    """Logs every episode that ended in ``batch`` (up to the episode budget) and advances the progress bar."""
    progress = run.progress
    for episode in finished_episodes(batch)[: max(run.cfg.train.episodes - progress.episodes, 0)]:
        progress.episodes += 1
        success = reached_goal(run.env_id, episode)
        if success and progress.first_success_episode is None:
            progress.first_success_episode = progress.episodes
        run.logger.log(
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
        if run.cfg.train.max_frames is None:
            run.bar.update(1)
        run.bar.set_postfix(
            episodes=progress.episodes, frames=progress.frames, ret=f"{episode.episode_return:.0f}", eps=f"{eps:.3f}"
        )


def _visited_states(batch: TensorDictBase, progress: Progress) -> tuple[torch.Tensor, torch.Tensor]:
    """Keeps every state the agent arrived in (``("next", "observation")``, so goal states count) with its 1-based episode."""
    steps = batch.transpose(0, 1) if batch.ndim == 2 else batch
    steps = steps.reshape(-1)
    done = steps["next", "done"].reshape(-1).long()
    ended_before = progress.episodes - int(done.sum())
    episode_ids = ended_before + 1 + torch.cumsum(done, 0) - done
    return steps["next", "observation"].cpu(), episode_ids.cpu()


def _periodic_evaluation(run: Run) -> None:
    """Greedy evaluation; keeps the best policy so far and notes the first solved evaluation."""
    result = evaluate(run.agent.actor, run.eval_env, run.env_id)
    note_evaluation(run, result, confirm=lambda: _final_evaluation(run))


def note_evaluation(run: Run, result: dict, *, confirm: Callable[[], dict]) -> None:
    """Logs a periodic evaluation's ``result``, keeps the best policy so far and notes the first solved evaluation.

    A result at or above the solved threshold is confirmed by ``confirm()``, the
    greedy returns of ``eval.final_episodes`` episodes (see :func:`_confirm_solved`).
    """
    progress = run.progress
    log_evaluation(result, run)
    mean = result["eval_return_mean"]
    if progress.best_eval_return is None or mean > progress.best_eval_return:
        progress.best_eval_return, progress.best_eval_frames = mean, progress.frames
        best = {"actor": run.agent.actor.state_dict(), "frames": progress.frames, "eval_return_mean": mean}
        save_atomically(best, run.run_dir / BEST_POLICY)
    rule = run.solved_rule
    if rule is not None and result[rule.metric] >= rule.threshold and progress.solved_at_frames is None:
        _confirm_solved(run, rule, confirm)


def _confirm_solved(run: Run, rule: SolvedRule, confirm: Callable[[], dict]) -> None:
    """Marks the task solved if an evaluation of ``eval.final_episodes`` episodes (``confirm()``) confirms the periodic one.

    A few periodic episodes at or above the threshold often come from a policy
    that averages below it; training goes on when the confirmation fails. With
    ``eval.final_episodes=0`` the periodic evaluation decides alone.
    """
    progress = run.progress
    if run.cfg.eval.final_episodes:
        result = confirm()
        log.info(
            "Confirming evaluation at %d frames (%d episodes): %s %.2f",
            progress.frames,
            run.cfg.eval.final_episodes,
            rule.metric,
            result[rule.metric],
        )
        if result[rule.metric] < rule.threshold:
            return
        run.confirmation = (progress.frames, result)
    progress.solved_at_frames, progress.solved_at_wall_time_s = progress.frames, round(progress.wall_time_s, 2)
    log.info(
        "Solved at %d frames (%.1f s), greedy %s >= %g",
        progress.frames,
        progress.wall_time_s,
        rule.metric,
        rule.threshold,
    )


def _final_evaluation(run: Run) -> dict:
    """Greedy returns of ``eval.final_episodes`` episodes played side by side (their own seeds)."""
    cfg = run.cfg
    final_env = make_run_env(cfg, num_envs=cfg.eval.final_episodes, seed=cfg.seed + 20_000)
    return evaluate(run.agent.actor, final_env, run.env_id)


def log_evaluation(result: dict, run: Run) -> None:
    """A row of the evaluations table, and the log line."""
    progress = run.progress
    run.logger.log("evaluations", {"frames": progress.frames, "episode": progress.episodes, **result})
    log.info("eval at %d frames: return %.1f", progress.frames, result["eval_return_mean"])


def save_checkpoint(run: Run) -> None:
    """Writes the checkpoint atomically (a crash mid-write keeps the previous one)."""
    checkpoint = {
        "format": CHECKPOINT_FORMAT,
        "config": OmegaConf.to_container(run.cfg, resolve=True),
        "agent": run.agent.state_dict(),
        "kept": {name: part.state_dict() for name, part in run.kept.items()},
        "progress": asdict(run.progress),
        "visited": run.visited if run.cfg.train.save_visited_states else None,
        "torch_rng": torch.get_rng_state(),
    }
    save_atomically(checkpoint, run.run_dir / CHECKPOINT)


def finish_run(run: Run, interrupt: StopOnInterrupt) -> dict:
    """Saves the last checkpoint, runs the final greedy evaluation and writes the summary.

    A Ctrl-C before or during the final evaluation exits with the checkpoint
    saved and the command that continues the run.
    """
    run.bar.close()
    save_checkpoint(run)
    episodes = run.cfg.eval.final_episodes
    final = None
    try:
        if confirmed_now(run):
            final = run.confirmation[1]  # the same policy, evaluated just now
        elif not interrupt.requested and episodes:
            log.info(
                "Final greedy evaluation: %d episodes side by side (Ctrl-C stops it; the checkpoint is saved).",
                episodes,
            )
            final = _final_evaluation(run)
    except KeyboardInterrupt:
        interrupt.requested = True
    if interrupt.requested:
        run.logger.close()
        raise SystemExit(
            f"Interrupted at {run.progress.frames} frames; checkpoint saved in {run.run_dir}. "
            f"Continue with: python train.py <same overrides> resume=true hydra.run.dir={run.run_dir}"
        )
    return close_run(run, final)


def confirmed_now(run: Run) -> bool:
    """Whether the evaluation that confirmed "solved" was of the policy as it is now (no frame since)."""
    return run.confirmation is not None and run.confirmation[0] == run.progress.frames


def close_run(run: Run, final: dict | None) -> dict:
    """Logs the ``final`` evaluation (if any), closes the logs and writes the summary, which it returns."""
    if final is not None:
        log_evaluation(final, run)
    run.logger.close()
    return write_summary(run, final)


def write_summary(run: Run, final: dict | None) -> dict:
    """``summary.json`` (see :data:`~torchrl_mbe.rundir.SUMMARY_FIELDS`) and visited states, if recorded."""
    cfg, progress, rule = run.cfg, run.progress, run.solved_rule
    final_return = final["eval_return_mean"] if final else None
    summary = {
        "env": with_size(run.env_id, cfg.env.size),  # DeepSea-20: one env per size in the report
        "method": method_name(cfg),
        "seed": cfg.seed,
        "tag": cfg.tag,
        "config_id": config_id(cfg),
        "frames": progress.frames,
        "episodes": progress.episodes,
        **dict.fromkeys((*UPDATE_COUNTERS, *logged_counters()), 0),
        **run.agent.summary_fields(),
        "wall_time_s": round(progress.wall_time_s, 2),
        "frames_per_s": round(progress.frames / max(progress.wall_time_s, 1e-9), 1),
        "first_success_episode": progress.first_success_episode,
        "final_eval_return": final_return,
        "final_eval_success_rate": final["eval_success_rate"] if final else None,
        "best_eval_return": progress.best_eval_return,
        "best_eval_frames": progress.best_eval_frames,
        "solved_threshold": rule.threshold if rule is not None else None,
        "solved_by": "success" if rule is not None and rule.metric == "eval_success_rate" else "return",
        "solved": None if final is None or rule is None else final[rule.metric] >= rule.threshold,
        "solved_at_frames": progress.solved_at_frames,
        "solved_at_wall_time_s": progress.solved_at_wall_time_s,
    }
    (run.run_dir / SUMMARY).write_text(json.dumps(summary, indent=2))
    if run.visited:
        observations, episode_ids = map(torch.cat, zip(*run.visited))
        np.save(run.run_dir / VISITED_STATES, observations.numpy().astype(np.float32))
        np.save(run.run_dir / VISITED_EPISODES, episode_ids.numpy())
    return summary


def summary_line(summary: dict, run_dir: Path | str) -> str:
    """One line a user reads at the end of a run: solved or not, the returns, time and where the files are."""
    final, threshold = summary["final_eval_return"], summary["solved_threshold"]
    if final is None:
        verdict = "No final evaluation"
    elif threshold is None:
        verdict = f"Final greedy return {final:.1f}"
    elif summary.get("solved_by") == "success":
        verdict = (
            f"{'SOLVED' if summary['solved'] else 'NOT SOLVED'}: final greedy success rate {summary['final_eval_success_rate']:.2f} "
            f"(threshold {threshold:g}), return {final:.2f}"
        )
    else:
        verdict = f"{'SOLVED' if summary['solved'] else 'NOT SOLVED'}: final greedy return {final:.1f} (threshold {threshold:g})"
    if summary["best_eval_return"] is not None:
        verdict += f", best periodic {summary['best_eval_return']:.1f}"
    if summary["solved_at_frames"] is not None:
        verdict += f", first solved evaluation at {summary['solved_at_frames']} frames / {summary['solved_at_wall_time_s']:.0f} s"
    return (
        f"{verdict}. {summary['frames']} frames, {summary['episodes']} episodes in {summary['wall_time_s']:.0f} s "
        f"({summary['frames_per_s']:.0f} frames/s). Run directory: {run_dir}"
    )


def crossed(frames: int, new_frames: int, every: int) -> bool:
    """Whether the last ``new_frames`` frames crossed a multiple of ``every``."""
    return frames // every > (frames - new_frames) // every
