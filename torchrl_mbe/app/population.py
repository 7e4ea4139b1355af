"""A training loop's bookkeeping: the runs of its ``M`` members, ``population=M`` (a single run is a population of one).

Every algorithm's loop (:mod:`torchrl_mbe.app.dqn`, :mod:`torchrl_mbe.app.reinforce`)
calls :func:`start_population` (which members its batch holds), builds its agent for
them, calls :func:`open_population`, names the parts whose state checkpoints keep
(:meth:`Population.keep`), and then, while :meth:`Population.training`, collects a
batch, calls :meth:`Population.record`, learns, records the updates and calls
:meth:`Population.evaluate_and_checkpoint_if_due`; it ends with :meth:`Population.finish`.

With ``population=M > 1`` the agent's networks carry a member dimension (see
docs/architecture.md, "Where the member dimension lives"): the env batch is
``(num_envs, M)`` and each member is a :class:`~torchrl_mbe.app.run.Run` writing
the run directory a single run writes (``<run_dir>/seed<s>``: the same tables,
``best_policy.pt`` loadable into a single actor, ``summary.json``), so the report
reads members and single runs alike. With ``M = 1`` the one run writes ``run_dir``
itself. A member stops (its final evaluation and summary written) when its own
budget is spent, or when solved with ``train.stop_when_solved``, and then leaves the
batch: the loop builds its parts again for the members still training, which go on
from their own state (:meth:`Population.leave_batch`), so a stopped member costs
nothing more. The loop ends when every member has stopped. One checkpoint, in
``run_dir``, resumes the whole population.
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
from torchrl_mbe.app.rollout import CollectorState, EnvState
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
    """Anything whose state a checkpoint keeps; in a population, with its members side by side."""

    def state_dict(self) -> dict: ...

    def load_state_dict(self, state: dict) -> None: ...

    def select_members(self, state: dict, index: list[int], num_members: int) -> dict:
        """``state`` (of ``num_members`` members) cut to the members ``index``, for this part (built for ``len(index)``)."""


class Agent(Protocol):
    """What the bookkeeping needs of an algorithm's agent."""

    actor: TensorDictModuleBase  # the greedy actor (evaluation, best policy), with the member dimension if M > 1

    def summary_fields(self) -> dict[str, int]: ...  # its update counters (rundir.UPDATE_COUNTERS, its explorer's)

    def state_dict(self) -> dict: ...  # everything it trains and counts

    def load_state_dict(self, state: dict) -> None: ...

    def select_members(self, state: dict, index: list[int], num_members: int) -> dict:
        """As :meth:`Resumable.select_members` (a population's agent only)."""


class Training(Protocol):
    """What a loop trains with, built for the members its batch holds (:meth:`Population.leave_batch` builds it again)."""

    agent: Agent

    def parts(self) -> dict[str, Resumable]: ...  # the parts whose state checkpoints keep beside the agent's


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
    ``in_batch`` lists the members whose columns the agent and the kept parts hold,
    in column order: all ``M`` at first, then those still training once others left.
    """

    cfg: DictConfig
    run_dir: Path  # the checkpoint; the members' run directories (member_dir)
    env_id: str
    agent: Agent
    eval_env: EnvBase  # eval.episodes copies (per member): one periodic evaluation is one batched rollout
    bar: tqdm
    in_batch: list[int]
    runs: dict[int, Run] = field(default_factory=dict)
    summaries: dict[int, dict] = field(default_factory=dict)
    stopped: dict[int, dict] = field(default_factory=dict)
    frames: int = 0
    started: float = field(default_factory=time.perf_counter)
    kept: dict[str, Resumable] = field(default_factory=dict)  # the loop's parts whose state checkpoints keep
    resumed: dict | None = None  # their states in the checkpoint this population resumed from
    resumed_columns: tuple[list[int], int] | None = None  # which of the checkpoint's columns stay, of how many
    last_return: float | None = None  # of the latest episode any member finished (the progress bar shows it)

    @property
    def size(self) -> int:
        """The number of members ``M`` (``population=M``)."""
        return self.cfg.population

    @property
    def width(self) -> int:
        """The number of members the batch holds (``M`` until members leave it)."""
        return len(self.in_batch)

    def active(self) -> list[tuple[int, Run]]:
        """The members still training, as ``(member, run)``."""
        return sorted(self.runs.items())

    def keep(self, name: str, part: Resumable) -> None:
        """Puts ``part``'s state into every checkpoint from now on; a resumed population restores it here."""
        self.kept[name] = part
        if self.resumed is not None:
            part.load_state_dict(self._selected(part, self.resumed[name]))

    def holds_stopped_members(self) -> bool:
        """Whether the batch holds a member that has stopped, beside members still training."""
        return bool(self.runs) and len(self.runs) < self.width

    def leave_batch(self, build: Callable[[int], Training]) -> Training:
        """The stopped members leave the batch: ``build(n)`` builds the loop's parts for the ``n`` members still training,
        which go on from their own state (the agent's and every kept part's, cut by ``select_members``).

        The members' random draws are the torch generator's, now for fewer members: the
        remaining members' states are unchanged, their next draws are not those they
        would have drawn beside the stopped ones.
        """
        index = [self.in_batch.index(member) for member in sorted(self.runs)]
        states = {name: _handover_state(part) for name, part in self.kept.items()}
        agent_state, width = self.agent.state_dict(), self.width
        training = build(len(index))
        training.agent.load_state_dict(training.agent.select_members(agent_state, index, width))
        self.agent, self.in_batch = training.agent, sorted(self.runs)
        self.eval_env = make_eval_env(self.cfg, self.width)
        parts = {"eval_env": EnvState(self.eval_env), **training.parts()}
        self.kept = {}
        for name, part in parts.items():
            self.kept[name] = part
            part.load_state_dict(part.select_members(states[name], index, width))
        log.info(
            "Stopped members left the batch; %d of %d train on (seed%s %s).",
            self.width,
            self.size,
            "s" * (self.width > 1),
            ", ".join(str(self.cfg.seed + member) for member in self.in_batch),
        )
        return training

    def training(self, interrupt: StopOnInterrupt) -> bool:
        """Stops the members that are done (final evaluation, summary); whether any trains on and no Ctrl-C came."""
        if not interrupt.requested:
            self._stop_finished_members(interrupt)
        return bool(self.runs) and not interrupt.requested

    def record(self, batch: TensorDictBase, *, eps: float = 0.0) -> None:
        """Counts a collected batch (a member's frames along its last dimension) and records each training member's part."""
        self.frames += batch.numel() // self.width
        for member, run in self.active():
            returns = record_frames(run, self._member_part(batch, member), eps=eps)
            self.last_return = returns[-1] if returns else self.last_return
        self._update_bar(eps)

    def record_updates(self, rows: list[dict]) -> None:
        """Logs each training member's part of the agent's update rows (a population's row holds a list per value)."""
        for member, run in self.active():
            column = self.column(member)
            record_updates(
                run,
                [
                    {key: value[column] if isinstance(value, list) else value for key, value in row.items()}
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
                column = self.column(member)
                note_evaluation(run, results[column], confirm=lambda column=column: final()[column])
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
            "in_batch": self.in_batch,
            "torch_rng": torch.get_rng_state(),
        }
        save_atomically(checkpoint, self.run_dir / CHECKPOINT)

    def summary(self) -> dict:
        """A single run's summary; for ``M > 1``, each member's with its run directory, the number solved and the mean final return."""
        return summary_of(self.summaries, self.run_dir)

    def column(self, member: int) -> int:
        """Where the batch holds ``member``."""
        return self.in_batch.index(member)

    def member_actor_state(self, member: int) -> dict:
        """The member's greedy actor weights, keyed as a single actor's (so ``best_policy.pt`` loads into one)."""
        actor = self.agent.actor
        if self.size == 1:
            return actor.state_dict()
        if isinstance(actor, BootstrappedQValueActor):  # its M * K heads stacked: the member's K
            return actor.member_state_dict(self.column(member))
        return member_state_dict(actor.state_dict(), self.column(member))

    def _selected(self, part: Resumable, state: dict) -> dict:
        """A resumed part's state, cut to the members that train on if some of the checkpoint's have left."""
        if self.resumed_columns is None:
            return state
        index, num_members = self.resumed_columns
        return part.select_members(state, index, num_members)

    def _member_part(self, batch: TensorDictBase, member: int) -> TensorDictBase:
        """A member's frames of a batch: the batch itself for a single run, its column of a ``(num_envs, M, time)`` one."""
        return batch if self.size == 1 else batch[:, self.column(member)]

    def _evaluate(self, env: EnvBase) -> list[dict]:
        """Each member's greedy results of one episode in each of its copies of ``env``, in one rollout."""
        if self.size == 1:
            return [evaluate(self.agent.actor, env, self.env_id)]
        return evaluate_members(self.agent.actor, env, self.env_id)

    def _final_evaluation(self) -> list[dict]:
        """Each member's greedy results of ``eval.final_episodes`` episodes played side by side (their own seeds)."""
        cfg = self.cfg
        return self._evaluate(
            make_run_env(cfg, num_envs=cfg.eval.final_episodes, seed=cfg.seed + 20_000, num_members=self.width)
        )

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
        return final()[self.column(member)] if self.cfg.eval.final_episodes else None

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


def summary_of(summaries: dict[int, dict], run_dir: Path) -> dict:
    """The summary of a population whose members' summaries are ``summaries`` (by member): a single run's own for one member."""
    if len(summaries) == 1:
        return summaries[0]
    members = [summaries[member] for member in range(len(summaries))]
    return population_summary(members, [str(member_dir(run_dir, summary["seed"], len(members))) for summary in members])


def member_dir(run_dir: Path, seed: int, population: int) -> Path:
    """Where the member of seed ``seed`` writes its run directory: ``run_dir`` for a single run, else ``<run_dir>/seed<seed>``."""
    return Path(run_dir) if population == 1 else Path(run_dir) / seeds_name(seed, 1)


@dataclass
class PopulationStart:
    """Where a population starts: each member's saved counters, and the members its batch holds.

    ``checkpoint`` is the one a resumed population goes on from; ``columns``, which of
    its batch's columns the new batch keeps (and of how many), when members left it.
    """

    member_states: list[dict]
    in_batch: list[int]
    checkpoint: dict | None = None
    columns: tuple[list[int], int] | None = None

    @property
    def num_members(self) -> int | None:
        """The members the loop builds its parts for (``None`` for a single run)."""
        return len(self.in_batch) if len(self.member_states) > 1 else None


def start_population(cfg: DictConfig, run_dir: Path) -> PopulationStart:
    """A new population (every member in the batch), or with ``cfg.resume`` its checkpoint's, whose batch keeps the members that train on.

    A member that had stopped goes on after a resume that raised its budget, if the
    batch still held it (it stopped at the checkpoint's frame).

    Raises:
        ConfigError: ``run_dir`` holds a run and ``resume`` is off; nothing to
            resume; an unreadable checkpoint or one of another config or version;
            a stopped member's summary is missing.
        RunFinished: ``resume`` on a population whose members have all stopped.
    """
    run_dir = Path(run_dir)
    if not cfg.resume:
        refuse_to_overwrite(run_dir)
        return PopulationStart([_fresh_member_state()] * cfg.population, list(range(cfg.population)))
    checkpoint = read_checkpoint(cfg, run_dir)
    saved_batch = checkpoint.get("in_batch", list(range(cfg.population)))  # written since members leave the batch
    members = checkpoint["members"]
    in_batch = [member for member in saved_batch if _trains_on(cfg.train, members[member], checkpoint["frames"])]
    if not in_batch:
        summaries = {
            member: _stopped_summary(member_dir(run_dir, cfg.seed + member, cfg.population))
            for member in range(cfg.population)
        }
        raise RunFinished(summary_of(summaries, run_dir))
    columns = (
        None if in_batch == saved_batch else ([saved_batch.index(member) for member in in_batch], len(saved_batch))
    )
    return PopulationStart(members, in_batch, checkpoint, columns)


def open_population(cfg: DictConfig, run_dir: Path, agent: Agent, start: PopulationStart | None = None) -> Population:
    """Starts the population's runs in ``run_dir`` (``start``, by default :func:`start_population`'s), the agent built for its batch.

    A resumed population's agent (and each part it keeps, :meth:`Population.keep`) goes
    on from the checkpoint, cut to the members its batch keeps.

    Raises:
        ConfigError, RunFinished: as :func:`start_population`.
    """
    run_dir = Path(run_dir)
    start = start_population(cfg, run_dir) if start is None else start
    eval_env = make_eval_env(cfg, start.num_members)
    population = Population(
        cfg, run_dir, resolve_env_id(cfg.env.name), agent, eval_env, _progress_bar(cfg), start.in_batch
    )
    checkpoint = start.checkpoint
    if checkpoint is not None:
        population.resumed_columns = start.columns
        agent.load_state_dict(population._selected(agent, checkpoint["agent"]))
        torch.set_rng_state(checkpoint["torch_rng"])
        population.frames = checkpoint["frames"]
        population.started -= checkpoint["wall_time_s"]
        population.resumed = checkpoint["kept"]
        log.info("Resumed at %d frames%s", population.frames, " per member" if cfg.population > 1 else "")
    for member, state in enumerate(start.member_states):
        _open_member(population, member, state)
    population.keep("eval_env", EnvState(eval_env))  # its start states go on where they stopped
    log.info("Run directory: %s", run_dir)
    population._update_bar(None)
    return population


def make_eval_env(cfg: DictConfig, num_members: int | None) -> EnvBase:
    """The periodic evaluation's env: ``eval.episodes`` copies for each of the ``num_members`` members the batch holds."""
    return make_run_env(cfg, num_envs=max(cfg.eval.episodes, 1), seed=cfg.seed + 10_000, num_members=num_members)


def _handover_state(part: Resumable) -> dict:
    """What a part hands to its successor within the process: its state, a gymnasium collector's live copies included."""
    return part.handover_state() if isinstance(part, CollectorState) else part.state_dict()


def _fresh_member_state() -> dict:
    return {"stopped": False, "progress": asdict(Progress()), "confirmation": None, "visited": None}


def _member_state(run: Run, *, stopped: bool) -> dict:
    """What a checkpoint keeps of a member: its counters, its confirmation of "solved" and its visited states."""
    visited = run.visited if run.cfg.train.save_visited_states else None
    return {"stopped": stopped, "progress": asdict(run.progress), "confirmation": run.confirmation, "visited": visited}


def _trains_on(train: DictConfig, state: dict, frames: int) -> bool:
    """Whether a checkpoint's member trains on: it had not stopped, or it stopped at the checkpoint's ``frames`` and its budget was raised since."""
    progress = Progress(**state["progress"])
    return not state["stopped"] or (progress.frames >= frames and not budget_spent(train, progress))


def _stopped_summary(directory: Path) -> dict:
    if not (directory / SUMMARY).exists():
        raise ConfigError(
            f"{directory / SUMMARY} is missing: the checkpoint says this run has stopped. Start a new run."
        )
    return json.loads((directory / SUMMARY).read_text())


def _open_member(population: Population, member: int, state: dict) -> None:
    """The member's run (its config is the population's with its own seed), or its summary if it is out of the batch."""
    cfg, size = population.cfg, population.size
    member_cfg = cfg if size == 1 else OmegaConf.merge(cfg, {"seed": cfg.seed + member})
    directory = member_dir(population.run_dir, member_cfg.seed, size)
    if member not in population.in_batch:
        population.summaries[member] = _stopped_summary(directory)
        population.stopped[member] = state
        return
    progress = Progress(**state["progress"])
    population.runs[member] = Run(
        member_cfg,
        directory,
        population.env_id,
        progress,
        RunLogger(directory, member_cfg, resume_frames=progress.frames if cfg.resume else None),
        functools.partial(population.member_actor_state, member),
        started=population.started,
        confirmation=state["confirmation"],
        visited=state["visited"] or [],
    )


def _progress_bar(cfg: DictConfig) -> tqdm:
    """Counts frames when the budget is in frames (``train.max_frames``), else episodes; off when not a terminal."""
    frames_budget = cfg.train.max_frames is not None
    return tqdm(
        total=cfg.train.max_frames if frames_budget else cfg.train.episodes,
        unit="frame" if frames_budget else "ep",
        unit_scale=frames_budget,
        disable=None if cfg.progress_bar else True,
    )
