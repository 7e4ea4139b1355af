"""The explorer registry: every ``exploration=`` option, its config schema and how it is built, in one place.

An explorer is a class here: its ``schema`` (the config dataclass of its
``exploration=`` option, registered with Hydra by :mod:`torchrl_mbe.app.config`)
and its :meth:`~Explorer.build`, which returns the explorer with a fixed shape:

* ``policy``: the TensorDictModule the collector runs (the greedy actor plus the exploring rule);
* ``eps``: the exploration rate now (0 for an explorer without one), annealed by :meth:`~Explorer.anneal`;
* hooks the DQN loop calls on every explorer alike: :meth:`~Explorer.observe` (fresh
  frames), :meth:`~Explorer.learn` (its own updates), :meth:`~Explorer.after_q_update`
  (on the Q update's batch), :meth:`~Explorer.log_fields`, :meth:`~Explorer.summary_fields`
  and its checkpoint state (:meth:`~Explorer.state_dict`).

The loop never asks which explorer it has. Adding one means adding a class (``base.py``
holds the contract, ``baselines.py`` and ``planning.py`` the explorers) and its line in :data:`EXPLORERS`; see ``docs/architecture.md``.
"""

from __future__ import annotations

from omegaconf import DictConfig

from torchrl_mbe.app.explorers.base import (
    EGreedyExploration,
    EGreedyExplorer,
    ExplorationConfig,
    Explorer,
    ExplorerContext,
    NoExploration,
    QEnsemble,
    QNetwork,
    eps_schedule,
)
from torchrl_mbe.app.explorers.baselines import (
    BootstrapExploration,
    BootstrapExplorer,
    NoisyExploration,
    NoisyExplorer,
    RNDExploration,
    RNDExplorer,
)
from torchrl_mbe.app.explorers.planning import (
    CountsExploration,
    CountsExplorer,
    DeepExploration,
    DeepExplorer,
    DiagonalExploration,
    DiagonalExplorer,
    DynamicsTraining,
    GaussianExploration,
    GaussianExplorer,
    KernelDensityExploration,
    KernelDensityExplorer,
    KernelExploration,
    KernelExplorer,
    KNearestExploration,
    KNearestExplorer,
    PlanningExploration,
    PlanningExplorer,
)

__all__ = [
    "EXPLORERS",
    "BootstrapExploration",
    "BootstrapExplorer",
    "CountsExploration",
    "CountsExplorer",
    "DeepExploration",
    "DeepExplorer",
    "DiagonalExploration",
    "DiagonalExplorer",
    "DynamicsTraining",
    "EGreedyExploration",
    "EGreedyExplorer",
    "ExplorationConfig",
    "Explorer",
    "ExplorerContext",
    "GaussianExploration",
    "GaussianExplorer",
    "KNearestExploration",
    "KNearestExplorer",
    "KernelDensityExploration",
    "KernelDensityExplorer",
    "KernelExploration",
    "KernelExplorer",
    "NoExploration",
    "NoisyExploration",
    "NoisyExplorer",
    "PlanningExploration",
    "PlanningExplorer",
    "QEnsemble",
    "QNetwork",
    "RNDExploration",
    "RNDExplorer",
    "eps_schedule",
    "explorer_of",
    "logged_columns",
    "logged_counters",
]


EXPLORERS: dict[str, type[Explorer]] = {
    explorer.schema.name: explorer
    for explorer in (
        GaussianExplorer,
        KernelExplorer,
        DiagonalExplorer,
        KNearestExplorer,
        KernelDensityExplorer,
        CountsExplorer,
        DeepExplorer,
        RNDExplorer,
        NoisyExplorer,
        BootstrapExplorer,
        EGreedyExplorer,
        Explorer,
    )
}
"""Every ``exploration=`` option by name: the planning ones (gaussian, kernel, diagonal, knn, kde, counts, deep),
TorchRL's RND and NoisyNet, Bootstrapped DQN with priors, e-greedy (random exploring actions) and none (never explores)."""


def logged_columns() -> tuple[str, ...]:
    """The updates table's columns of every registered explorer, in registry order (the run directory's header)."""
    return tuple(dict.fromkeys(column for explorer in EXPLORERS.values() for column in explorer.log_columns))


def logged_counters() -> tuple[str, ...]:
    """The summary's counters of every registered explorer, in registry order."""
    return tuple(dict.fromkeys(counter for explorer in EXPLORERS.values() for counter in explorer.counters))


def explorer_of(exploration: DictConfig) -> type[Explorer]:
    """The registered explorer of an ``exploration`` config (its name is one of :data:`EXPLORERS`, by the schema).

    Examples:
        >>> from omegaconf import OmegaConf
        >>> from torchrl_mbe.app.explorers import KernelExploration, explorer_of
        >>> explorer_of(OmegaConf.structured(KernelExploration())).__name__
        'KernelExplorer'
    """
    return EXPLORERS[exploration.name]
