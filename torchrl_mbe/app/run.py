"""One training run's record: its counters, tables, evaluations, best policy and summary.

A :class:`Run` is what one seed writes in its run directory (the files of
:mod:`torchrl_mbe.rundir`). The loop never holds a ``Run`` itself: it holds a
:class:`~torchrl_mbe.app.population.Population`, whose members are runs (a single
run is a population of one), and which calls :func:`record_frames`,
:func:`record_updates`, :func:`note_evaluation` and :func:`close_run` for each.
"""

from __future__ import annotations

import json
import logging
import os
import platform
import subprocess
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import tensordict
import torch
import torchrl
from omegaconf import DictConfig
from tensordict import TensorDictBase

import torchrl_mbe
from torchrl_mbe.app.checkpoints import save_atomically
from torchrl_mbe.app.explorers import logged_counters
from torchrl_mbe.app.identity import config_id, method_name, with_size
from torchrl_mbe.app.loggers import RunLogger
from torchrl_mbe.envs import finished_episodes, reached_goal
from torchrl_mbe.envs.registry import SolvedRule, solved_rule
from torchrl_mbe.rundir import BEST_POLICY, SUMMARY, UPDATE_COUNTERS, VISITED_EPISODES, VISITED_STATES

__all__ = [
    "Progress",
    "Run",
    "RunFinished",
    "budget_spent",
    "close_run",
    "confirmed_now",
    "crossed",
    "hydra_command",
    "log_evaluation",
    "note_evaluation",
    "record_frames",
    "record_updates",
    "summary_line",
]

log = logging.getLogger(__name__)


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
    """One seed's run: its config, directory, counters and logs.

    ``actor_state`` returns the greedy actor's weights as a single actor's (a
    population's member gives its slice), which ``best_policy.pt`` keeps.
    """

    cfg: DictConfig
    run_dir: Path
    env_id: str
    progress: Progress
    logger: RunLogger
    actor_state: Callable[[], dict]
    started: float = field(default_factory=time.perf_counter)
    confirmation: tuple[int, dict] | None = None  # (frames, result) of the evaluation that confirmed "solved"
    visited: list = field(default_factory=list)  # (observations, episode ids) per batch, with train.save_visited_states

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


def record_frames(run: Run, batch: TensorDictBase, *, eps: float = 0.0) -> list[float]:
    """Counts the collected ``batch`` (``(time,)`` or ``(envs, time)``), logs the episodes that ended in it
    (with ``eps``, the exploration rate that acted) and records visited states if asked; returns those episodes' returns."""
    progress = run.progress
    progress.frames += batch.numel()
    progress.wall_time_s = time.perf_counter() - run.started
    returns = _record_episodes(run, batch, eps)
    if run.cfg.train.save_visited_states:
        run.visited.append(_visited_states(batch, progress))
    return returns


def record_updates(run: Run, rows: list[dict]) -> None:
    """Logs rows of the updates table, each with the throughput so far."""
    progress = run.progress
    for row in rows:
        run.logger.log("updates", {**row, "frames_per_s": progress.frames / max(progress.wall_time_s, 1e-9)})


def _record_episodes(run: Run, batch: TensorDictBase, eps: float) -> list[float]:
    """Logs every episode that ended in ``batch`` (up to the episode budget); returns their returns."""
    progress, returns = run.progress, []
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
        returns.append(episode.episode_return)
    return returns


def _visited_states(batch: TensorDictBase, progress: Progress) -> tuple[torch.Tensor, torch.Tensor]:
    """Keeps every state the agent arrived in (``("next", "observation")``, so goal states count) with its 1-based episode."""
    steps = batch.transpose(0, 1) if batch.ndim == 2 else batch
    steps = steps.reshape(-1)
    done = steps["next", "done"].reshape(-1).long()
    ended_before = progress.episodes - int(done.sum())
    episode_ids = ended_before + 1 + torch.cumsum(done, 0) - done
    return steps["next", "observation"].cpu(), episode_ids.cpu()


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
        best = {"actor": run.actor_state(), "frames": progress.frames, "eval_return_mean": mean}
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


def log_evaluation(result: dict, run: Run) -> None:
    """A row of the evaluations table, and the log line."""
    progress = run.progress
    run.logger.log("evaluations", {"frames": progress.frames, "episode": progress.episodes, **result})
    log.info("eval at %d frames: return %.1f", progress.frames, result["eval_return_mean"])


def confirmed_now(run: Run) -> bool:
    """Whether the evaluation that confirmed "solved" was of the policy as it is now (no frame since)."""
    return run.confirmation is not None and run.confirmation[0] == run.progress.frames


def close_run(run: Run, final: dict | None, counters: dict[str, int]) -> dict:
    """Logs the ``final`` evaluation (if any), closes the logs and writes the summary with the agent's ``counters``; returns it."""
    if final is not None:
        log_evaluation(final, run)
    run.logger.close()
    return write_summary(run, final, counters)


def write_summary(run: Run, final: dict | None, counters: dict[str, int]) -> dict:
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
        **counters,
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
        "record": run_record(cfg),
    }
    (run.run_dir / SUMMARY).write_text(json.dumps(summary, indent=2))
    if run.visited:
        observations, episode_ids = map(torch.cat, zip(*run.visited))
        np.save(run.run_dir / VISITED_STATES, observations.numpy().astype(np.float32))
        np.save(run.run_dir / VISITED_EPISODES, episode_ids.numpy())
    return summary


def run_record(cfg: DictConfig) -> dict:
    """Where a result comes from: the code's commit, the machine, the library versions and the command.

    ``commit`` is the checkout's ``HEAD`` (``None`` outside a git checkout; ``dirty``
    says whether tracked files differed from it); ``command`` is the Hydra command
    line (``None`` for a ``train(cfg)`` call from Python).
    """
    checkout = Path(torchrl_mbe.__file__).resolve().parents[1]
    commit = _git(checkout, "rev-parse", "HEAD")
    return {
        "commit": commit,
        "dirty": bool(_git(checkout, "status", "--porcelain", "--untracked-files=no")) if commit else None,
        "cpu": _cpu_model(),
        "cores": os.cpu_count(),
        "device": torch.cuda.get_device_name(cfg.device) if str(cfg.device).startswith("cuda") else "cpu",
        "versions": {
            "torch": torch.__version__,
            "torchrl": torchrl.__version__,
            "tensordict": tensordict.__version__,
            "torchrl_mbe": torchrl_mbe.__version__,
        },
        "command": hydra_command(),
    }


def _git(checkout: Path, *args: str) -> str | None:
    try:
        done = subprocess.run(
            ["git", "-C", str(checkout), *args], check=False, capture_output=True, text=True, timeout=10
        )
    except (OSError, subprocess.TimeoutExpired):
        return None
    return done.stdout.strip() if done.returncode == 0 else None


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as cpuinfo:
            return next(line.split(":", 1)[1].strip() for line in cpuinfo if line.startswith("model name"))
    except (OSError, StopIteration):
        return platform.processor() or platform.machine()


def hydra_command() -> str | None:
    """The command line of this Hydra job (``None`` outside Hydra), or of the one that launched this process's part."""
    from hydra.core.hydra_config import HydraConfig

    if not HydraConfig.initialized():
        return os.environ.get(LAUNCHING_COMMAND)
    return " ".join(["python train.py", *HydraConfig.get().overrides.task])


LAUNCHING_COMMAND = "TORCHRL_MBE_COMMAND"
"""The environment variable through which a population's parts (:mod:`torchrl_mbe.app.processes`) learn their command."""


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
