"""A training loop's bookkeeping: the runs of its ``M`` members, ``population=M`` (a single run is a population of one).

Every algorithm's loop (:mod:`torchrl_mbe.app.dqn`, :mod:`torchrl_mbe.app.reinforce`)
builds its agent, calls :func:`open_population`, names the parts whose state
checkpoints keep (:meth:`Population.keep`), and then, while
:meth:`Population.training`, collects a batch, calls :meth:`Population.record`,
learns, records the updates and calls :meth:`Population.evaluate_and_checkpoint_if_due`;
it ends with :meth:`Population.finish`.

With ``population=M > 1`` the agent's networks carry a member dimension (see
docs/architecture.md, "Where the member dimension lives"): the env batch is
``(num_envs, M)`` and each member is a :class:`~torchrl_mbe.app.run.Run` writing
the run directory a single run writes (``<run_dir>/seed<s>``: the same tables,
``best_policy.pt`` loadable into a single actor, ``summary.json``), so the report
reads members and single runs alike. With ``M = 1`` the one run writes ``run_dir``
itself. A member stops (its final evaluation and summary written) when its own
budget is spent, or when solved with ``train.stop_when_solved``; its networks then
go on computing with the others', unrecorded. The loop ends when every member has
stopped. One checkpoint, in ``run_dir``, resumes the whole population.
"""

from __future__ import annotations

import functools
import json
import logging
import signal
import statistics
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Protocol

import torch
from omegaconf import DictConfig, OmegaConf
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.envs import EnvBase
from tqdm.auto import tqdm

from torchrl_mbe.app.checkpoints import CHECKPOINT_FORMAT, read_checkpoint, refuse_to_overwrite, save_atomically
from torchrl_mbe.app.config import ConfigError
from torchrl_mbe.app.environments import make_run_env
from torchrl_mbe.app.evaluation import evaluate, evaluate_members
from torchrl_mbe.app.identity import seeds_name
from torchrl_mbe.app.loggers import RunLogger
from torchrl_mbe.app.rollout import EnvState
from torchrl_mbe.app.run import (
    Progress,
    Run,
    RunFinished,
    budget_spent,
    close_run,
    confirmed_now,
    crossed,
    note_evaluation,
    record_frames,
    record_updates,
    summary_line,
)
from torchrl_mbe.envs import resolve_env_id
from torchrl_mbe.modules.bootstrap import BootstrappedQValueActor
from torchrl_mbe.modules.networks import member_state_dict
from torchrl_mbe.rundir import CHECKPOINT, SUMMARY

__all__ = ["Agent", "Population", "Resumable", "StopOnInterrupt", "member_dir", "open_population", "population_summary"]

log = logging.getLogger(__name__)
tqdm.set_lock(threading.RLock())  # tqdm's default lock is a multiprocessing semaphore, left behind by a killed run


class Resumable(Protocol):
    """Anything whose state a checkpoint keeps."""

    def state_dict(self) -> dict: ...

    def load_state_dict(self, state: dict) -> None: ...


class Agent(Protocol):
    """What the bookkeeping needs of an algorithm's agent."""

    actor: TensorDictModuleBase  # the greedy actor (evaluation, best policy), with the member dimension if M > 1

    def summary_fields(self) -> dict[str, int]: ...  # its update counters (rundir.UPDATE_COUNTERS, its explorer's)

    def state_dict(self) -> dict: ...  # everything it trains and counts

    def load_state_dict(self, state: dict) -> None: ...


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


@dataclass
class Population:
    """The shared parts of a loop's members (agent, evaluation env, checkpoint, progress bar) and their runs.

    ``runs`` holds the members still training, by member index; a stopped
    member's summary is in ``summaries`` and the counters it stopped with in
    ``stopped`` (which checkpoints keep). ``frames`` counts each member's frames.
    """

    cfg: DictConfig
    run_dir: Path  # the checkpoint; the members' run directories (member_dir)
    env_id: str
    agent: Agent
    eval_env: EnvBase  # eval.episodes copies (per member): one periodic evaluation is one batched rollout
    bar: tqdm
    runs: dict[int, Run] = field(default_factory=dict)
    summaries: dict[int, dict] = field(default_factory=dict)
    stopped: dict[int, dict] = field(default_factory=dict)
    frames: int = 0
    started: float = field(default_factory=time.perf_counter)
    kept: dict[str, Resumable] = field(default_factory=dict)  # the loop's parts whose state checkpoints keep
    resumed: dict | None = None  # their states in the checkpoint this population resumed from
    last_return: float | None = None  # of the latest episode any member finished (the progress bar shows it)

    @property
    def size(self) -> int:
        """The number of members ``M`` (``population=M``)."""
        return self.cfg.population

    def active(self) -> list[tuple[int, Run]]:
        """The members still training, as ``(member, run)``."""
        return sorted(self.runs.items())

    def keep(self, name: str, part: Resumable) -> None:
        """Puts ``part``'s state into every checkpoint from now on; a resumed population restores it here."""
        self.kept[name] = part
        if self.resumed is not None:
            part.load_state_dict(self.resumed[name])

    def training(self, interrupt: StopOnInterrupt) -> bool:
        """Stops the members that are done (final evaluation, summary); whether any trains on and no Ctrl-C came."""
        if not interrupt.requested:
            self._stop_finished_members(interrupt)
        return bool(self.runs) and not interrupt.requested

    def record(self, batch: TensorDictBase, *, eps: float = 0.0) -> None:
        """Counts a collected batch (a member's frames along its last dimension) and records each training member's part."""
        self.frames += batch.numel() // self.size
        for member, run in self.active():
            returns = record_frames(run, self._member_part(batch, member), eps=eps)
            self.last_return = returns[-1] if returns else self.last_return
        self._update_bar(eps)

    def record_updates(self, rows: list[dict]) -> None:
        """Logs each training member's part of the agent's update rows (a population's row holds a list per value)."""
        for member, run in self.active():
            record_updates(
                run,
                [
                    {key: value[member] if isinstance(value, list) else value for key, value in row.items()}
                    for row in rows
                ],
            )

    def evaluate_and_checkpoint_if_due(self, new_frames: int) -> None:
        """The members' periodic greedy evaluation (one rollout) and the checkpoint, when the last ``new_frames`` crossed their period."""
        cfg = self.cfg
        if crossed(self.frames, new_frames, cfg.eval.every_frames) and cfg.eval.episodes:
            results = self._evaluate(self.eval_env)
            final = functools.cache(self._final_evaluation)  # played once, if a member's result asks for confirmation
            for member, run in self.active():
                note_evaluation(run, results[member], confirm=lambda member=member: final()[member])
        if crossed(self.frames, new_frames, cfg.train.checkpoint_every_frames):
            self.save_checkpoint()

    def finish(self, interrupt: StopOnInterrupt) -> dict:
        """Saves the last checkpoint; after a Ctrl-C exits with the command that continues, else returns the summary.

        The summary is the run's ``summary.json`` for a single run, the population's
        (each member's under ``"members"``) for ``M > 1``.
        """
        self.bar.close()
        self.save_checkpoint()
        if interrupt.requested:
            for _, run in self.active():
                run.logger.close()
            per_member = " per member" if self.size > 1 else ""
            raise SystemExit(
                f"Interrupted at {self.frames} frames{per_member}; checkpoint saved in {self.run_dir}. "
                f"Continue with: python train.py <same overrides> resume=true hydra.run.dir={self.run_dir}"
            )
        return self.summary()

    def save_checkpoint(self) -> None:
        """The whole population's checkpoint, atomically: the agent, the kept parts and each member's counters."""
        members = [
            self.stopped[member] if member in self.stopped else _member_state(self.runs[member], stopped=False)
            for member in range(self.size)
        ]
        checkpoint = {
            "format": CHECKPOINT_FORMAT,
            "config": OmegaConf.to_container(self.cfg, resolve=True),
            "agent": self.agent.state_dict(),
            "kept": {name: part.state_dict() for name, part in self.kept.items()},
            "frames": self.frames,
            "wall_time_s": time.perf_counter() - self.started,
            "members": members,
            "torch_rng": torch.get_rng_state(),
        }
        save_atomically(checkpoint, self.run_dir / CHECKPOINT)

    def summary(self) -> dict:
        """A single run's summary; for ``M > 1``, each member's with its run directory, the number solved and the mean final return."""
        if self.size == 1:
            return self.summaries[0]
        summaries = [self.summaries[member] for member in range(self.size)]
        return population_summary(
            summaries, [str(member_dir(self.run_dir, summary["seed"], self.size)) for summary in summaries]
        )

    def _member_part(self, batch: TensorDictBase, member: int) -> TensorDictBase:
        """A member's frames of a batch: the batch itself for a single run, ``batch[:, member]`` of a ``(num_envs, M, time)`` one."""
        return batch if self.size == 1 else batch[:, member]

    def _evaluate(self, env: EnvBase) -> list[dict]:
        """Each member's greedy results of one episode in each of its copies of ``env``, in one rollout."""
        if self.size == 1:
            return [evaluate(self.agent.actor, env, self.env_id)]
        return evaluate_members(self.agent.actor, env, self.env_id)

    def _final_evaluation(self) -> list[dict]:
        """Each member's greedy results of ``eval.final_episodes`` episodes played side by side (their own seeds)."""
        cfg = self.cfg
        return self._evaluate(make_run_env(cfg, num_envs=cfg.eval.final_episodes, seed=cfg.seed + 20_000))

    def _stop_finished_members(self, interrupt: StopOnInterrupt) -> None:
        """Stops the members whose budget is spent (or that are solved, with ``train.stop_when_solved``): final evaluation, summary.

        The final evaluation draws on a fork of torch's generator: a stopped member
        changes nothing in what the others (or this run, resumed with a larger budget)
        draw. A second Ctrl-C during it stops nobody: the checkpoint is saved and a
        resume evaluates them.
        """
        finishing = [(member, run) for member, run in self.active() if run.budget_spent()]
        final = functools.cache(self._forked_final_evaluation)
        for member, run in finishing:
            try:
                result = self._final_result(member, run, final)
            except KeyboardInterrupt:
                interrupt.requested = True
                return
            self.summaries[member] = close_run(run, result, self.agent.summary_fields())
            self.stopped[member] = _member_state(run, stopped=True)
            del self.runs[member]
            if self.size > 1:
                line = summary_line(self.summaries[member], run.run_dir)
                log.info("Member %d of %d stopped. %s", member + 1, self.size, line)
        if finishing:
            self._update_bar(None)

    def _final_result(self, member: int, run: Run, final: Callable[[], list[dict]]) -> dict | None:
        """The stopping member's final result: its confirming evaluation if the policy is unchanged since, else ``final()``'s."""
        if confirmed_now(run):
            return run.confirmation[1]
        return final()[member] if self.cfg.eval.final_episodes else None

    def _forked_final_evaluation(self) -> list[dict]:
        log.info("Final greedy evaluation: %d episodes side by side.", self.cfg.eval.final_episodes)
        with torch.random.fork_rng():
            return self._final_evaluation()

    def _update_bar(self, eps: float | None) -> None:
        """The bar counts the slowest member's episodes (frames with ``train.max_frames``); its postfix says how many solved."""
        runs = [run for _, run in self.active()]
        if runs:
            frames_budget = self.cfg.train.max_frames is not None
            self.bar.n = self.frames if frames_budget else min(run.progress.episodes for run in runs)
        postfix = {"solved": f"{self._solved_count()}/{self.size}"}
        if self.last_return is not None:
            postfix["ret"] = f"{self.last_return:.0f}"
        if eps is not None:
            postfix["eps"] = f"{eps:.3f}"
        self.bar.set_postfix(postfix)

    def _solved_count(self) -> int:
        running = sum(run.progress.solved_at_frames is not None for _, run in self.active())
        return running + sum(summary["solved_at_frames"] is not None for summary in self.summaries.values())


def population_summary(members: list[dict], run_dirs: list[str]) -> dict:
    """A population's summary: each member's summary and run directory, the number solved, the mean final greedy return
    (``None`` if one is missing)."""
    finals = [member["final_eval_return"] for member in members]
    return {
        "population": len(members),
        "members": members,
        "run_dirs": run_dirs,
        "solved": sum(bool(member["solved"]) for member in members),
        "final_eval_return": None if None in finals else statistics.fmean(finals),
    }


def member_dir(run_dir: Path, seed: int, population: int) -> Path:
    """Where the member of seed ``seed`` writes its run directory: ``run_dir`` for a single run, else ``<run_dir>/seed<seed>``."""
    return Path(run_dir) if population == 1 else Path(run_dir) / seeds_name(seed, 1)


def open_population(cfg: DictConfig, run_dir: Path, agent: Agent) -> Population:
    """Starts the population's runs in ``run_dir``, or resumes them from its checkpoint with ``cfg.resume``.

    Raises:
        ConfigError: ``run_dir`` holds a run and ``resume`` is off; nothing to
            resume; an unreadable checkpoint or one of another config or version;
            a stopped member's summary is missing.
        RunFinished: ``resume`` on a population whose members have all stopped.
    """
    run_dir = Path(run_dir)
    eval_env = make_run_env(cfg, num_envs=max(cfg.eval.episodes, 1), seed=cfg.seed + 10_000)
    if not cfg.resume:
        refuse_to_overwrite(run_dir)
    checkpoint = read_checkpoint(cfg, run_dir) if cfg.resume else None
    population = Population(cfg, run_dir, resolve_env_id(cfg.env.name), agent, eval_env, _progress_bar(cfg))
    member_states = [_fresh_member_state()] * cfg.population
    if checkpoint is not None:
        agent.load_state_dict(checkpoint["agent"])
        torch.set_rng_state(checkpoint["torch_rng"])
        population.frames, member_states = checkpoint["frames"], checkpoint["members"]
        population.started -= checkpoint["wall_time_s"]
        population.resumed = checkpoint["kept"]
        log.info("Resumed at %d frames%s", population.frames, " per member" if cfg.population > 1 else "")
    for member, state in enumerate(member_states):
        _open_member(population, member, state)
    population.keep("eval_env", EnvState(eval_env))  # its start states go on where they stopped
    if not population.runs:
        population.bar.close()
        raise RunFinished(population.summary())
    log.info("Run directory: %s", run_dir)
    population._update_bar(None)
    return population


def _fresh_member_state() -> dict:
    return {"stopped": False, "progress": asdict(Progress()), "confirmation": None, "visited": None}


def _member_state(run: Run, *, stopped: bool) -> dict:
    """What a checkpoint keeps of a member: its counters, its confirmation of "solved" and its visited states."""
    visited = run.visited if run.cfg.train.save_visited_states else None
    return {"stopped": stopped, "progress": asdict(run.progress), "confirmation": run.confirmation, "visited": visited}


def _open_member(population: Population, member: int, state: dict) -> None:
    """The member's run (its config is the population's with its own seed), or its summary if it stays stopped.

    A member that had stopped goes on after a resume that raised its budget, if it
    stopped at the checkpoint's frame (since then its networks trained on, unrecorded).
    """
    cfg, size = population.cfg, population.size
    member_cfg = cfg if size == 1 else OmegaConf.merge(cfg, {"seed": cfg.seed + member})
    directory = member_dir(population.run_dir, member_cfg.seed, size)
    progress = Progress(**state["progress"])
    if state["stopped"] and (progress.frames < population.frames or budget_spent(member_cfg.train, progress)):
        if not (directory / SUMMARY).exists():
            raise ConfigError(
                f"{directory / SUMMARY} is missing: the checkpoint says this run has stopped. Start a new run."
            )
        population.summaries[member] = json.loads((directory / SUMMARY).read_text())
        population.stopped[member] = state
        return
    population.runs[member] = Run(
        member_cfg,
        directory,
        population.env_id,
        progress,
        RunLogger(directory, member_cfg, resume_frames=progress.frames if cfg.resume else None),
        _actor_state(population.agent, member, size),
        started=population.started,
        confirmation=state["confirmation"],
        visited=state["visited"] or [],
    )


def _actor_state(agent: Agent, member: int, size: int) -> Callable[[], dict]:
    """The member's greedy actor weights, keyed as a single actor's (so ``best_policy.pt`` loads into one)."""
    if size == 1:
        return agent.actor.state_dict
    if isinstance(agent.actor, BootstrappedQValueActor):  # its M * K heads stacked: the member's K
        return lambda: agent.actor.member_state_dict(member)
    return lambda: member_state_dict(agent.actor.state_dict(), member)


def _progress_bar(cfg: DictConfig) -> tqdm:
    """Counts frames when the budget is in frames (``train.max_frames``), else episodes; off when not a terminal."""
    frames_budget = cfg.train.max_frames is not None
    return tqdm(
        total=cfg.train.max_frames if frames_budget else cfg.train.episodes,
        unit="frame" if frames_budget else "ep",
        unit_scale=frames_budget,
        disable=None if cfg.progress_bar else True,
    )
