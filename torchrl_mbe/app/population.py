"""``population=M``: the DQN agents of seeds ``seed`` .. ``seed+M-1`` trained as one batched program.

:func:`train_dqn_population` is :func:`~torchrl_mbe.app.dqn.train_dqn`'s loop over a
member dimension (see docs/architecture.md, "Where the member dimension lives", for where it lives in
each tensor): one env batch ``(num_envs, M)``, one collector, one
:class:`~torchrl_mbe.app.replay.PopulationReplayBuffer`, one agent whose
networks, dynamics models, novelty windows and input statistics carry the member
dimension and whose gradient steps clip per member. The bookkeeping is per member:
each member is a :class:`~torchrl_mbe.app.run.Run` writing the run directory a
single run writes (``<run_dir>/seed<s>``: the same tables, ``best_policy.pt`` loadable
into a single actor, ``summary.json``), so the report reads members and single runs
alike. A member stops (its final evaluation and summary written) when its own
budget is spent, or when solved with ``train.stop_when_solved``; its networks then
go on computing with the others, unrecorded. The process ends when every member
has stopped. One checkpoint, in ``run_dir``, resumes the whole population.
"""

from __future__ import annotations

import functools
import json
import logging
import statistics
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import torch
from omegaconf import DictConfig, OmegaConf
from tensordict import TensorDictBase
from torchrl.collectors import Collector
from torchrl.envs import EnvBase
from tqdm.auto import tqdm

from torchrl_mbe.app.checkpoints import CHECKPOINT_FORMAT, read_checkpoint, refuse_to_overwrite, save_atomically
from torchrl_mbe.app.config import ConfigError, seeds_name
from torchrl_mbe.app.dqn import DQNAgent, build_dqn_agent
from torchrl_mbe.app.evaluation import evaluate_members
from torchrl_mbe.app.loggers import RunLogger
from torchrl_mbe.app.replay import PopulationReplayBuffer, ReplayTransitions, check_replay_fits
from torchrl_mbe.app.rollout import CollectorState, EnvState
from torchrl_mbe.app.run import (
    Progress,
    Resumable,
    Run,
    RunFinished,
    StopOnInterrupt,
    budget_spent,
    close_run,
    confirmed_now,
    crossed,
    keep_in_checkpoints,
    make_run_env,
    note_evaluation,
    record_frames,
    record_updates,
    summary_line,
)
from torchrl_mbe.envs import resolve_env_id
from torchrl_mbe.modules.networks import member_state_dict
from torchrl_mbe.rundir import CHECKPOINT, SUMMARY

__all__ = ["Population", "member_dir", "train_dqn_population"]

log = logging.getLogger(__name__)


def train_dqn_population(cfg: DictConfig, run_dir: Path) -> dict:
    """Trains ``cfg.population`` DQN agents together; returns the population's summary (each member's in ``"members"``)."""
    members = cfg.population
    env = make_run_env(cfg, num_envs=cfg.env.num_envs, seed=cfg.seed)  # (num_envs, M)
    check_replay_fits(cfg.buffer, env, members, cfg.device, run_dir)
    agent = build_dqn_agent(cfg, env)
    replay_buffer = PopulationReplayBuffer(cfg.buffer.size, members, device=cfg.device)
    # Built before a resume restores torch's generator: checking the policy draws from it.
    collector = Collector(
        env, agent.explorer.policy, frames_per_batch=cfg.collector.frames_per_batch * members, total_frames=-1
    )
    population = open_population(cfg, run_dir, agent)
    keep_in_checkpoints(population, "replay_buffer", replay_buffer)
    transitions = ReplayTransitions(
        cfg.algo.n_steps, cfg.algo.gamma, intrinsic_coef=agent.explorer.intrinsic_coef, num_members=members
    )
    keep_in_checkpoints(population, "transitions", transitions)
    keep_in_checkpoints(population, "collector", CollectorState(collector))
    batches = iter(collector)
    with StopOnInterrupt() as interrupt:
        while population.active() and not interrupt.requested:
            batch = next(batches)  # (num_envs, M, time)
            stored = transitions(batch)
            if stored is not None:
                replay_buffer.extend(stored)
            record_member_frames(population, batch)
            record_member_updates(population, agent.learn(batch, replay_buffer, population.frames))
            evaluate_and_checkpoint_if_due(population, batch.numel() // members)
            stop_finished_members(population)
    try:
        return finish_population(population, interrupt)
    finally:
        collector.shutdown()


@dataclass
class Population:
    """A population's shared parts (agent, evaluation env, checkpoint) and its members' runs.

    ``runs`` holds the members still training, by member index; a stopped
    member's summary is in ``summaries`` and the counters it stopped with in
    ``stopped`` (which checkpoints keep).
    """

    cfg: DictConfig
    run_dir: Path  # the checkpoint; the members' run directories inside (member_dir)
    env_id: str
    agent: DQNAgent
    eval_env: EnvBase  # (eval.episodes, M)
    runs: dict[int, Run]
    summaries: dict[int, dict]
    stopped: dict[int, dict]
    bar: tqdm
    frames: int = 0  # each member's
    started: float = field(default_factory=time.perf_counter)
    kept: dict[str, Resumable] = field(default_factory=dict)  # what keep_in_checkpoints adds
    resumed: dict | None = None

    def active(self) -> list[tuple[int, Run]]:
        return sorted(self.runs.items())


def member_dir(run_dir: Path, seed: int) -> Path:
    """Where the member of seed ``seed`` writes its run directory: ``<run_dir>/seed<seed>``."""
    return Path(run_dir) / seeds_name(seed, 1)


class MemberAgent:
    """What a member's :class:`~torchrl_mbe.app.run.Run` reads of the population's agent.

    Its ``actor``'s state is the member's slice, keyed as a single run's actor
    (so ``best_policy.pt`` loads into one); the update counters are the population's.
    """

    def __init__(self, agent: DQNAgent, member: int) -> None:
        self.agent, self.actor = agent, _MemberActor(agent, member)

    def summary_fields(self) -> dict[str, int]:
        return self.agent.summary_fields()


class _MemberActor:
    def __init__(self, agent: DQNAgent, member: int) -> None:
        self.agent, self.member = agent, member

    def state_dict(self) -> dict:
        return member_state_dict(self.agent.actor.state_dict(), self.member)


def open_population(cfg: DictConfig, run_dir: Path, agent: DQNAgent) -> Population:
    """Starts the population in ``run_dir``, or resumes it from its checkpoint with ``cfg.resume``.

    Raises:
        ConfigError: as :func:`~torchrl_mbe.app.run.open_run` does; a stopped member's summary is missing.
        RunFinished: ``resume`` on a population whose members have all stopped.
    """
    run_dir = Path(run_dir)
    eval_env = make_run_env(cfg, num_envs=max(cfg.eval.episodes, 1), seed=cfg.seed + 10_000)
    if not cfg.resume:
        refuse_to_overwrite(run_dir)
    checkpoint = read_checkpoint(cfg, run_dir) if cfg.resume else None
    if checkpoint is not None:
        agent.load_state_dict(checkpoint["agent"])
        torch.set_rng_state(checkpoint["torch_rng"])
    member_states = checkpoint["members"] if checkpoint is not None else [_fresh_member_state()] * cfg.population
    population = Population(
        cfg,
        run_dir,
        resolve_env_id(cfg.env.name),
        agent,
        eval_env,
        runs={},
        summaries={},
        stopped={},
        bar=_population_bar(cfg),
        frames=checkpoint["frames"] if checkpoint is not None else 0,
    )
    population.started -= checkpoint["wall_time_s"] if checkpoint is not None else 0.0
    for member, state in enumerate(member_states):
        _open_member(population, member, state)
    if checkpoint is not None:
        population.resumed = checkpoint["kept"]
        log.info("Resumed the population at %d frames per member", population.frames)
    keep_in_checkpoints(population, "eval_env", EnvState(population.eval_env))
    if not population.runs:
        population.bar.close()
        raise RunFinished(population_summary(population))
    _update_bar(population)
    return population


def _fresh_member_state() -> dict:
    return {"stopped": False, "progress": asdict(Progress()), "confirmation": None, "visited": None}


def _open_member(population: Population, member: int, state: dict) -> None:
    """The member's run (its config is the population's with its own seed), or its summary if it stays stopped.

    A member that had stopped goes on after a resume that raised its budget, if it
    stopped at the checkpoint's frame (since then its networks trained on, unrecorded).
    """
    cfg = population.cfg
    member_cfg = OmegaConf.merge(cfg, {"seed": cfg.seed + member})
    directory = member_dir(population.run_dir, member_cfg.seed)
    progress = Progress(**state["progress"])
    if state["stopped"] and (progress.frames < population.frames or budget_spent(member_cfg.train, progress)):
        if not (directory / SUMMARY).exists():
            raise ConfigError(
                f"{directory / SUMMARY} is missing: the checkpoint says this member has stopped. Start a new population."
            )
        population.summaries[member] = json.loads((directory / SUMMARY).read_text())
        population.stopped[member] = state
        return
    logger = RunLogger(directory, member_cfg, resume_frames=progress.frames if cfg.resume else None)
    population.runs[member] = Run(
        member_cfg,
        directory,
        population.env_id,
        population.eval_env,
        MemberAgent(population.agent, member),
        progress,
        logger,
        tqdm(disable=True),  # the population's bar shows every member
        started=population.started,
        confirmation=state["confirmation"],
        visited=state["visited"] or [],
    )


def _population_bar(cfg: DictConfig) -> tqdm:
    """Counts the slowest member's episodes (frames with ``train.max_frames``); members solved and stopped in the postfix."""
    frames_budget = cfg.train.max_frames is not None
    return tqdm(
        total=cfg.train.max_frames if frames_budget else cfg.train.episodes,
        unit="frame" if frames_budget else "ep",
        unit_scale=frames_budget,
        disable=None if cfg.progress_bar else True,
    )


def _update_bar(population: Population) -> None:
    bar, runs = population.bar, [run for _, run in population.active()]
    if runs:
        bar.n = (
            population.frames
            if population.cfg.train.max_frames is not None
            else min(run.progress.episodes for run in runs)
        )
    members = population.cfg.population
    bar.set_postfix(
        solved=f"{_solved_count(population)}/{members}",
        stopped=f"{len(population.summaries)}/{members}",
        eps=f"{population.agent.eps:.3f}",
    )


def _solved_count(population: Population) -> int:
    running = sum(run.progress.solved_at_frames is not None for _, run in population.active())
    return running + sum(summary["solved_at_frames"] is not None for summary in population.summaries.values())


def record_member_frames(population: Population, batch: TensorDictBase) -> None:
    """Counts a population's ``(num_envs, M, time)`` batch and records each training member's ``(num_envs, time)`` part."""
    population.frames += batch.numel() // population.cfg.population
    for member, run in population.active():
        record_frames(run, batch[:, member], eps=population.agent.eps)
    _update_bar(population)


def record_member_updates(population: Population, rows: list[dict]) -> None:
    """Logs each training member's part of the agent's update rows (a list holds one value per member)."""
    for member, run in population.active():
        record_updates(
            run,
            [{key: value[member] if isinstance(value, list) else value for key, value in row.items()} for row in rows],
        )


def evaluate_and_checkpoint_if_due(population: Population, new_frames: int) -> None:
    """The members' periodic greedy evaluation (one rollout) and the checkpoint, when the last ``new_frames`` crossed their period."""
    cfg = population.cfg
    if crossed(population.frames, new_frames, cfg.eval.every_frames) and cfg.eval.episodes:
        results = evaluate_members(population.agent.actor, population.eval_env, population.env_id)
        # played once, if a member's result asks for confirmation
        final = functools.cache(lambda: _final_evaluation(population))
        for member, run in population.active():
            note_evaluation(run, results[member], confirm=lambda member=member: final()[member])
    if crossed(population.frames, new_frames, cfg.train.checkpoint_every_frames):
        save_checkpoint(population)


def stop_finished_members(population: Population) -> None:
    """Stops the members whose budget is spent (or that are solved, with ``train.stop_when_solved``): final evaluation, summary."""
    finishing = [(member, run) for member, run in population.active() if run.budget_spent()]
    final = functools.cache(lambda: _final_evaluation(population))
    for member, run in finishing:
        if confirmed_now(run):
            result = run.confirmation[1]  # the same policy, evaluated just now
        else:
            result = final()[member] if population.cfg.eval.final_episodes else None
        population.summaries[member] = close_run(run, result)
        population.stopped[member] = _member_state(run, stopped=True)
        del population.runs[member]
        log.info(
            "Member %d of %d stopped. %s",
            member + 1,
            population.cfg.population,
            summary_line(population.summaries[member], run.run_dir),
        )
    if finishing:
        _update_bar(population)


def _final_evaluation(population: Population) -> list[dict]:
    """Every member's greedy returns of ``eval.final_episodes`` episodes, in one ``(final_episodes, M)`` rollout."""
    cfg = population.cfg
    final_env = make_run_env(cfg, num_envs=cfg.eval.final_episodes, seed=cfg.seed + 20_000)
    return evaluate_members(population.agent.actor, final_env, population.env_id)


def save_checkpoint(population: Population) -> None:
    """The whole population's checkpoint, atomically: the agent, the shared parts and each member's counters."""
    members = [
        population.stopped[member]
        if member in population.stopped
        else _member_state(population.runs[member], stopped=False)
        for member in range(population.cfg.population)
    ]
    checkpoint = {
        "format": CHECKPOINT_FORMAT,
        "config": OmegaConf.to_container(population.cfg, resolve=True),
        "agent": population.agent.state_dict(),
        "kept": {name: part.state_dict() for name, part in population.kept.items()},
        "frames": population.frames,
        "wall_time_s": time.perf_counter() - population.started,
        "members": members,
        "torch_rng": torch.get_rng_state(),
    }
    save_atomically(checkpoint, population.run_dir / CHECKPOINT)


def _member_state(run: Run, *, stopped: bool) -> dict:
    """What a checkpoint keeps of a member: its counters, its confirmation of "solved" and its visited states."""
    visited = run.visited if run.cfg.train.save_visited_states else None
    return {"stopped": stopped, "progress": asdict(run.progress), "confirmation": run.confirmation, "visited": visited}


def finish_population(population: Population, interrupt: StopOnInterrupt) -> dict:
    """Saves the last checkpoint; after a Ctrl-C exits with the command that continues, else returns the population's summary."""
    population.bar.close()
    save_checkpoint(population)
    if interrupt.requested:
        for _, run in population.active():
            run.logger.close()
        raise SystemExit(
            f"Interrupted at {population.frames} frames per member; checkpoint saved in {population.run_dir}. "
            f"Continue with: python train.py <same overrides> resume=true hydra.run.dir={population.run_dir}"
        )
    return population_summary(population)


def population_summary(population: Population) -> dict:
    """Each member's summary and run directory, the number solved, and the mean final greedy return (``None`` if one is missing)."""
    summaries = [population.summaries[member] for member in range(population.cfg.population)]
    finals = [summary["final_eval_return"] for summary in summaries]
    return {
        "population": population.cfg.population,
        "members": summaries,
        "run_dirs": [str(member_dir(population.run_dir, summary["seed"])) for summary in summaries],
        "solved": sum(bool(summary["solved"]) for summary in summaries),
        "final_eval_return": None if None in finals else statistics.fmean(finals),
    }
