"""The app's config schema: every setting, its default and what it accepts, in one place.

The schema is a tree of dataclasses (Hydra structured configs). :func:`register_configs`
puts it in Hydra's ``ConfigStore``: the root as ``base_config`` (``conf/config.yaml``
extends it) and every option of a choice group (``algo``, ``exploration``, ``dynamics``,
``buffer``, ``logger``) under its name, so ``exploration=kernel`` selects
:class:`~torchrl_mbe.app.explorers.KernelExploration` (each explorer's schema lives
beside it in :mod:`torchrl_mbe.app.explorers`) with its defaults. Files in ``conf/`` only override values:
``conf/env/`` holds each environment's settings, ``conf/experiment/`` the presets.

Hydra checks types and key names while composing. :func:`check_config` then checks
every value once, before anything is built: each field carries its rule
(:func:`setting`), and the rules that tie fields together follow. A bad value
raises :class:`ConfigError` naming the key, the value and what is accepted.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Dict, Optional

import torch
from hydra.core.config_store import ConfigStore
from omegaconf import MISSING, DictConfig, OmegaConf

from torchrl_mbe.app.environments import config_observation_spec
from torchrl_mbe.app.explorers import EXPLORERS, PlanningExplorer, explorer_of
from torchrl_mbe.app.explorers.planning import DYNAMICS, table_refusal
from torchrl_mbe.app.identity import method_name, seeds_name, with_size
from torchrl_mbe.app.loggers import BACKENDS, backend_unavailable
from torchrl_mbe.app.observation import matched
from torchrl_mbe.app.settings import (
    DISCOUNT,
    FRACTION,
    LAYERS,
    NON_NEGATIVE,
    NON_NEGATIVE_INT,
    POSITIVE,
    POSITIVE_INT,
    PROBABILITY,
    ConfigError,
    one_of,
    setting,
)
from torchrl_mbe.envs.registry import TASKS, Task, resolve_env_id, task_of
from torchrl_mbe.modules.dynamics import OUTPUTS, check_output
from torchrl_mbe.modules.exploration import check_eps_schedule

__all__ = [
    "Config",
    "ConfigError",
    "DQNConfig",
    "ReinforceConfig",
    "check_config",
    "register_configs",
    "with_env_group",
]


@dataclass
class EnvConfig:
    name: str = "mountaincar"  # a short name (conf/env/), any discrete-action gymnasium id, or module:EnvId
    num_envs: int = setting(1, POSITIVE_INT)  # >1: a batch of envs, one novelty window each
    size: Optional[int] = setting(None, POSITIVE_INT.or_none())  # env=deepsea: the grid's side N (bsuite: 10 to 50)
    # gym.make's keyword arguments: +env.make_kwargs.is_slippery=false
    make_kwargs: Dict[str, Any] = field(default_factory=dict)


@dataclass
class DQNConfig:
    """DQN (TorchRL's QValueActor + DQNLoss); per-environment values live in ``conf/env/``."""

    name: str = "dqn"
    num_cells: list[int] = setting([64, 64], LAYERS)  # Q-network hidden layers
    gamma: float = setting(0.99, DISCOUNT)
    n_steps: int = setting(1, POSITIVE_INT)  # n-step returns (1: the paper)
    lr: float = setting(2e-3, POSITIVE)  # Adam
    # linear decay over these frames (after learning_starts)
    lr_decay_frames: Optional[int] = setting(None, POSITIVE_INT.or_none())
    lr_end_factor: float = setting(1.0, FRACTION)  # the learning rate ends at lr * lr_end_factor
    batch_size: int = setting(256, POSITIVE_INT)
    learning_starts: int = setting(1000, NON_NEGATIVE_INT)  # frames collected before the first update
    updates_per_frame: float = setting(0.25, NON_NEGATIVE)  # gradient steps per collected frame (the paper: 1)
    eps_init: float = setting(1.0, PROBABILITY)
    eps_end: float = setting(0.05, PROBABILITY)
    eps_annealing_frames: int = setting(20_000, POSITIVE_INT)  # frames (counted from learning_starts) to eps_end
    eps_schedule: str = setting("linear", one_of("linear", "exponential"))  # exponential: the paper's x0.9995
    max_grad_norm: Optional[float] = setting(10.0, POSITIVE.or_none())  # null: no clipping
    standardize_inputs: bool = True  # the Q-network reads observations standardized with buffer statistics
    loss_function: str = setting("smooth_l1", one_of("l2", "smooth_l1"))  # smooth_l1: the paper's error clipping
    double_dqn: bool = True
    target_update: str = setting("hard", one_of("hard", "soft"))
    hard_update_interval: int = setting(250, POSITIVE_INT)  # updates between target copies
    soft_update_tau: float = setting(0.005, FRACTION)  # Polyak weight of the online network


@dataclass
class ReinforceConfig:
    """REINFORCE, the paper's policy-gradient baseline (its Table 2); explores by sampling its policy."""

    name: str = "reinforce"
    num_cells: list[int] = setting([10], LAYERS)  # one hidden layer of 10 tanh units
    gamma: float = setting(0.995, DISCOUNT)
    lr: float = setting(0.02, POSITIVE)
    weight_std: float = setting(0.3, NON_NEGATIVE)  # every layer's weights start N(0, weight_std)
    bias_init: float = 0.1


@dataclass
class DynamicsConfig:
    # oracle: the true dynamics (MountainCar, DeepSea); table: each (cell, action)'s observed successor (one-hot states)
    name: str = setting("mlp", one_of(*DYNAMICS))
    num_cells: list[int] = setting([64, 64], LAYERS)
    lr: float = setting(1e-3, POSITIVE)
    batch_size: int = setting(256, POSITIVE_INT)
    learning_starts: int = setting(256, NON_NEGATIVE_INT)  # frames before the first update (inputs normalized then)
    updates_per_frame: float = setting(0.25, NON_NEGATIVE)
    max_grad_norm: Optional[float] = setting(10.0, POSITIVE.or_none())
    prior_scale: float = setting(0.0, NON_NEGATIVE)  # a frozen random network's weight in each prediction (0: none)
    # the prior's hidden layers (null: num_cells)
    prior_num_cells: Optional[list[int]] = setting(None, LAYERS.or_none())
    normalize: bool = True  # standardize inputs and deltas; false keeps raw units (one-hot observations)
    output: str = setting("delta", one_of(*OUTPUTS))  # categorical: a softmax over a one-hot observation's entries


@dataclass
class BufferConfig:
    name: str = setting("uniform", one_of("uniform", "prioritized"))
    size: int = setting(100_000, POSITIVE_INT)
    alpha: float = setting(0.6, NON_NEGATIVE)  # prioritized only
    beta: float = setting(0.4, NON_NEGATIVE)


@dataclass
class CollectorConfig:
    frames_per_batch: int = setting(16, POSITIVE_INT)  # frames collected between two rounds of updates


@dataclass
class LoggerConfig:
    backend: str = setting("csv", one_of(*BACKENDS))  # CSV tables are always written; wandb, tensorboard mirror them
    mode: str = setting("offline", one_of("offline", "online"))  # wandb only; WANDB_MODE wins
    project: str = "torchrl-mbe"
    log_every_updates: int = setting(250, NON_NEGATIVE_INT)  # 0: no updates.csv rows


@dataclass
class TrainConfig:
    episodes: int = setting(400, POSITIVE_INT)  # budget in episodes
    max_frames: Optional[int] = setting(None, POSITIVE_INT.or_none())  # optional cap on frames
    checkpoint_every_frames: int = setting(20_000, POSITIVE_INT)
    save_visited_states: bool = False  # write visited_states.npy (the coverage experiment)
    # end at the first periodic evaluation at or above the solved threshold that eval.final_episodes confirm
    stop_when_solved: bool = False


@dataclass
class EvalConfig:
    every_frames: int = setting(20_000, POSITIVE_INT)  # periodic greedy evaluation
    episodes: int = setting(10, NON_NEGATIVE_INT)
    final_episodes: int = setting(100, NON_NEGATIVE_INT)  # greedy episodes at the end; 0 skips


@dataclass
class Config:
    """The root of the schema (``base_config``)."""

    env: EnvConfig = field(default_factory=EnvConfig)
    algo: Any = MISSING  # DQNConfig or ReinforceConfig
    exploration: Any = MISSING  # the schema of an explorer (torchrl_mbe.app.explorers.EXPLORERS)
    dynamics: DynamicsConfig = field(default_factory=DynamicsConfig)
    buffer: BufferConfig = field(default_factory=BufferConfig)
    collector: CollectorConfig = field(default_factory=CollectorConfig)
    logger: LoggerConfig = field(default_factory=LoggerConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)
    seed: int = setting(0, NON_NEGATIVE_INT)
    # >1: agents of seeds seed .. seed+population-1 trained as one batched program
    population: int = setting(1, POSITIVE_INT)
    # a population's members split into this many processes side by side, at most one per member (null: one per core; one on cuda)
    processes: Optional[int] = setting(None, POSITIVE_INT.or_none())
    device: str = "cpu"  # cpu or cuda[:N]: networks, buffers and the collector's policy
    tag: str = "default"  # part of the run directory; presets set their own
    resume: bool = False  # continue the run in hydra.run.dir from its last checkpoint
    progress_bar: bool = True
    torch_threads: Optional[int] = setting(1, POSITIVE_INT.or_none())  # null keeps torch's default
    compile: bool = False  # torch.compile the update step (falls back to eager if compilation fails)
    # a one-hot observation gets the categorical model and visit counts (torchrl_mbe.app.observation)
    match_observation: bool = True


def register_configs() -> None:
    """Stores the schema and every group option in Hydra's ``ConfigStore``, and the ``method_name`` resolver (idempotent).

    ``train.py`` and :func:`~torchrl_mbe.app.train` call it; so must anything
    that composes ``conf/`` itself (tests, benchmarks).
    """
    store = ConfigStore.instance()
    store.store(name="base_config", node=Config)
    store.store(group="algo", name="dqn", node=DQNConfig)
    store.store(group="algo", name="reinforce", node=ReinforceConfig)
    for name, explorer in EXPLORERS.items():
        store.store(group="exploration", name=name, node=explorer.schema)
    for name in DYNAMICS:
        store.store(group="dynamics", name=name, node=DynamicsConfig(name=name))
    for name in ("uniform", "prioritized"):
        store.store(group="buffer", name=name, node=BufferConfig(name=name))
    for backend in BACKENDS:
        store.store(group="logger", name=backend, node=LoggerConfig(backend=backend))
    if not OmegaConf.has_resolver("method_name"):  # lets conf/ name run directories after the method
        # the method of the explorer its observation gets (torchrl_mbe.app.observation.matched)
        OmegaConf.register_new_resolver("method_name", lambda *, _root_: method_name(matched(_root_)))
    if not OmegaConf.has_resolver("env_name"):  # ... and after the env, with its size
        OmegaConf.register_new_resolver("env_name", lambda *, _root_: with_size(_root_.env.name, _root_.env.size))
    if not OmegaConf.has_resolver("seeds"):  # ... and after the seed, or a population's seeds
        OmegaConf.register_new_resolver("seeds", lambda *, _root_: seeds_name(_root_.seed, _root_.population))


def with_env_group(overrides: list[str]) -> list[str]:
    """The command line with the env group ``env.name=X`` alone means: X's own file in ``conf/env/``, else ``env=gym``.

    So ``python train.py env.name=FrozenLake-v1`` trains with the generic settings
    (``conf/tuned/gym_dqn.yaml``), not with the default env's tuned ones. A command
    line that names ``env=`` or an ``experiment=`` keeps its own.

    Examples:
        >>> from torchrl_mbe.app.config import with_env_group
        >>> with_env_group(["env.name=FrozenLake-v1"]), with_env_group(["env.name=MiniGrid-Empty-5x5-v0"])
        (['env=gym', 'env.name=FrozenLake-v1'], ['env=minigrid', 'env.name=MiniGrid-Empty-5x5-v0'])
        >>> with_env_group(["env.name=acrobot", "seed=1"]), with_env_group(["env=deepsea", "env.size=20"])
        (['env=acrobot', 'env.name=acrobot', 'seed=1'], ['env=deepsea', 'env.size=20'])
    """
    names = [override.split("=", 1)[1] for override in overrides if override.startswith("env.name=")]
    if not names or any(override.startswith(("env=", "experiment=")) for override in overrides):
        return overrides
    groups = {_env_group(name) for name in names[-1].split(",")}
    return [f"env={groups.pop() if len(groups) == 1 else 'gym'}", *overrides]


def _env_group(name: str) -> str:
    """The ``conf/env/`` file of an env name: its registry alias (a suite's too), else ``gym``."""
    try:
        task = task_of(resolve_env_id(name))
    except ValueError:
        return "gym"  # the config check names what is wrong with it
    return task.alias if task is not None else "gym"


def check_config(cfg: DictConfig) -> None:
    """Raises :class:`ConfigError` for the first bad value of a composed config.

    Examples:
        >>> from omegaconf import OmegaConf
        >>> from torchrl_mbe.app.config import Config, DQNConfig, check_config
        >>> from torchrl_mbe.app.explorers import GaussianExploration
        >>> cfg = OmegaConf.structured(Config(algo=DQNConfig(gamma=1.5), exploration=GaussianExploration()))
        >>> check_config(cfg)
        Traceback (most recent call last):
        ...
        torchrl_mbe.app.settings.ConfigError: algo.gamma=1.5: expected a discount in [0, 1].
    """
    config = OmegaConf.to_object(cfg)
    _check_fields(config, "")
    _check_together(config)
    if is_planning(config) and config.dynamics.name == "table":
        _check_table(cfg)


def _check_fields(node: Any, prefix: str) -> None:
    for spec in dataclasses.fields(node):
        value, key = getattr(node, spec.name), prefix + spec.name
        if dataclasses.is_dataclass(value):
            _check_fields(value, key + ".")
        elif "rule" in spec.metadata and not spec.metadata["rule"].test(value):
            raise ConfigError(f"{key}={value!r}: expected {spec.metadata['rule'].accepted}.")


def _check_together(config: Config) -> None:
    """The rules that tie several settings together."""
    try:
        env_id = resolve_env_id(config.env.name, **config.env.make_kwargs)
    except ValueError as error:
        raise ConfigError(f"env.name={config.env.name!r}: {error}") from None
    _check_device(config.device)
    _check_env_options(config.env, task_of(env_id))
    if (missing := backend_unavailable(config.logger.backend)) is not None:
        raise ConfigError(f"logger={config.logger.backend}: {missing}")
    num_envs, frames_per_batch = config.env.num_envs, config.collector.frames_per_batch
    if isinstance(config.algo, ReinforceConfig) and num_envs != 1:
        raise ConfigError(f"env.num_envs={num_envs}: algo=reinforce plays one episode at a time; use env.num_envs=1.")
    if frames_per_batch % num_envs:
        raise ConfigError(
            f"collector.frames_per_batch={frames_per_batch}: expected a multiple of env.num_envs={num_envs}."
        )
    if isinstance(config.algo, DQNConfig):
        algo = config.algo
        try:
            check_eps_schedule(algo.eps_init, algo.eps_end, algo.eps_annealing_frames, algo.eps_schedule)
        except ValueError as error:  # the exploration module's own rule, named by the keys it reads
            raise ConfigError(f"algo (eps_init, eps_end, eps_schedule): {error}") from None
    if is_planning(config) and config.dynamics.name == "oracle" and getattr(task_of(env_id), "oracle", None) is None:
        with_oracle = ", ".join(alias for alias, task in TASKS.items() if task.oracle is not None)
        raise ConfigError(
            f"dynamics=oracle: {config.env.name} has no oracle dynamics (those that have: {with_oracle}); use dynamics=mlp."
        )
    try:
        check_output(config.dynamics.output, config.dynamics.normalize)
    except ValueError as error:  # the dynamics model's own rule, named by the keys it reads
        raise ConfigError(f"dynamics (output, normalize): {error}") from None
    if config.population > 1:
        _check_population(config)


def _check_table(cfg: DictConfig) -> None:
    if (refusal := table_refusal(cfg, config_observation_spec(cfg))) is not None:
        raise ConfigError(f"dynamics=table: {refusal}")


def _check_env_options(env: EnvConfig, task: Task | None) -> None:
    """``env.size`` and ``env.make_kwargs`` of a torch-only task: only what its registry entry takes (a gymnasium task's ``gym.make`` checked them)."""
    options = task.options if task is not None else ()
    if env.size is not None and "size" not in options:
        with_size = ", ".join(alias for alias, entry in TASKS.items() if "size" in entry.options)
        raise ConfigError(
            f"env.size={env.size}: {env.name} has no size (those that have: {with_size}); leave it unset (null)."
        )
    if task is not None and not task.gymnasium and (unknown := sorted(set(env.make_kwargs) - set(options))):
        raise ConfigError(f"env.make_kwargs: {env.name} takes {', '.join(options)}, not {', '.join(unknown)}.")


def _check_population(config: Config) -> None:
    """What a population (``population > 1``) trains with: DQN and uniform replay (every explorer batches its members)."""
    refusal = f"population={config.population}"
    if not isinstance(config.algo, DQNConfig):
        raise ConfigError(f"{refusal}: only algo=dqn trains populations; use population=1 for algo={config.algo.name}.")
    if config.buffer.name != "uniform":
        raise ConfigError(
            f"{refusal}: buffer={config.buffer.name} keeps one priority tree for all members; use buffer=uniform or population=1."
        )
    if is_planning(config) and config.exploration.model_error_threshold is not None:
        raise ConfigError(
            f"{refusal}: exploration.model_error_threshold switches one warm-up for all members; leave it null or use population=1."
        )


def _check_device(device: str) -> None:
    accepted = "cpu, or cuda / cuda:N on a machine with a CUDA GPU"
    try:
        parsed = torch.device(device)
    except RuntimeError:
        raise ConfigError(f"device={device!r}: expected {accepted}.") from None
    if parsed.type == "cuda" and not torch.cuda.is_available():
        raise ConfigError(f"device={device!r}: CUDA is not available on this machine; expected {accepted}.")
    if parsed.type == "cuda" and (parsed.index or 0) >= torch.cuda.device_count():
        raise ConfigError(f"device={device!r}: this machine has {torch.cuda.device_count()} CUDA device(s).")
    if parsed.type not in ("cpu", "cuda"):
        raise ConfigError(f"device={device!r}: expected {accepted}.")


def is_planning(cfg: DictConfig | Config) -> bool:
    """Whether the configured explorer plans with a dynamics model."""
    return issubclass(explorer_of(cfg.exploration), PlanningExplorer)
