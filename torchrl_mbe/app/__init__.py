"""The Hydra app: the config schema, the run's life, one training loop per algorithm, logging.

``train.py`` at the repository root is the thin ``@hydra.main`` wrapper around :func:`train`.
"""

from torchrl_mbe.app.config import ConfigError, check_config, register_configs
from torchrl_mbe.app.run import summary_line
from torchrl_mbe.app.train import train

__all__ = ["ConfigError", "check_config", "register_configs", "summary_line", "train"]
