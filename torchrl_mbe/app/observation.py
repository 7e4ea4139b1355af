"""The explorer matched to the observation: read from the env's spec, never from its name.

A one-hot observation (a TorchRL ``OneHot`` spec: DeepSea's cells, gymnasium's
``Discrete`` states such as FrozenLake's, Taxi's, CliffWalking's; or a ``MultiOneHot``
one of several categorical variables: Blackjack's three numbers, a ``MultiDiscrete``) gets what ``experiment=deepsea_categorical`` chose on
DeepSea (docs/results.md, section 6): the categorical dynamics model (a softmax over
each variable's values, a randomized prior and the offset that cancels it where the
model has data) and the diagonal Gaussian of every visited state, which on one-hot
entries ranks them by their visit counts; the Q-network reads the raw one-hot
entries. Deep exploration (``exploration.novelty_discount`` set) of one run on cells
(a ``OneHot`` state) gets the transition table instead (``dynamics=table``): a pair
tried once is known, an untried one leads somewhere new. Any other observation keeps
the configured explorer and model.

Settings the command line names (``exploration=...``, ``dynamics.num_cells=...``),
presets (``experiment=``, which set ``match_observation: false``) and
``match_observation=false`` win: only what nobody chose follows the observation.
"""

from __future__ import annotations

from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf
from torchrl.data import MultiOneHot, OneHot, TensorSpec

from torchrl_mbe.app.environments import config_observation_spec
from torchrl_mbe.app.explorers import DiagonalExploration, GaussianExploration, PlanningExplorer, explorer_of
from torchrl_mbe.app.explorers.planning import table_refusal

__all__ = [
    "CATEGORICAL_DYNAMICS",
    "COUNTS_EXPLORATION",
    "match_observation",
    "matched",
    "named_on_command_line",
    "observation_kind",
]

CATEGORICAL_DYNAMICS = {
    "output": "categorical",
    "normalize": False,
    "num_cells": [256],
    "prior_num_cells": [32],
    "prior_scale": 25.0,
}
"""The dynamics model of a one-hot observation (``experiment=deepsea_categorical``'s)."""

COUNTS_EXPLORATION = DiagonalExploration(window=None, min_variance=1e-8, added_variance=1e-3)
"""The explorer of a one-hot observation: every visited state's diagonal Gaussian (visit counts), a variance added to keep rare cells in order."""


def observation_kind(observation_spec: TensorSpec) -> str:
    """``"one-hot"`` for a ``OneHot`` or ``MultiOneHot`` observation spec, else ``"vector"``.

    Examples:
        >>> from torchrl_mbe import make_env
        >>> from torchrl_mbe.app.observation import observation_kind
        >>> observation_kind(make_env("FrozenLake-v1").observation_spec["observation"]), observation_kind(make_env("cartpole").observation_spec["observation"])
        ('one-hot', 'vector')
        >>> observation_kind(make_env("Blackjack-v1").observation_spec["observation"])  # three categorical variables
        'one-hot'
    """
    return "one-hot" if isinstance(observation_spec, (OneHot, MultiOneHot)) else "vector"


def match_observation(cfg: DictConfig, observation_spec: TensorSpec, named: set[str]) -> list[str]:
    """Sets what a one-hot observation needs in ``cfg``, where nobody chose otherwise; returns the changes, as ``key=value``.

    Args:
        cfg (DictConfig): the run's config (changed in place).
        observation_spec (TensorSpec): the training env's observation spec.
        named (set of str): the keys the command line sets (``exploration``, ``dynamics.num_cells``, ...).
    """
    if not cfg.match_observation or observation_kind(observation_spec) != "one-hot" or cfg.algo.name != "dqn":
        return []
    changes = []
    if not _names(named, "exploration") and cfg.exploration.name == GaussianExploration.name:
        cfg.exploration = OmegaConf.structured(COUNTS_EXPLORATION)
        changes.append("exploration=diagonal (window=null, added_variance=1e-3)")
    plans = issubclass(explorer_of(cfg.exploration), PlanningExplorer)  # the only explorers with a dynamics model
    if plans and not _names(named, "dynamics") and cfg.dynamics.name == "mlp":
        if _tabulates(cfg, observation_spec):
            cfg.dynamics.name = "table"
            changes.append("dynamics=table")
        else:
            for key, value in CATEGORICAL_DYNAMICS.items():
                cfg.dynamics[key] = value
                changes.append(f"dynamics.{key}={value}")
    if not _names(named, "algo.standardize_inputs"):
        cfg.algo.standardize_inputs = False
        changes.append("algo.standardize_inputs=false")
    return changes


def _tabulates(cfg: DictConfig, observation_spec: TensorSpec) -> bool:
    """Whether the run gets the transition table: deep exploration of one run on cells (one ``OneHot`` group), planned one step at a time."""
    deep = cfg.exploration.get("novelty_discount") is not None
    return deep and table_refusal(cfg, observation_spec) is None


def matched(cfg: DictConfig) -> DictConfig:
    """A copy of ``cfg`` as :func:`match_observation` changes it for its env, the command line read from Hydra: what the run will train."""
    cfg = cfg.copy()
    match_observation(cfg, config_observation_spec(cfg), named_on_command_line())
    return cfg


def named_on_command_line() -> set[str]:
    """The keys the command line of this Hydra job sets (none outside Hydra)."""
    if not HydraConfig.initialized():
        return set()
    return {override.split("=", 1)[0].lstrip("+~") for override in HydraConfig.get().overrides.task}


def _names(named: set[str], key: str) -> bool:
    """Whether the command line sets ``key`` or anything under it."""
    return any(name == key or name.startswith(key + ".") for name in named)
