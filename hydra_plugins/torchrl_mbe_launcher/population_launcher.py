"""``hydra/launcher=population``: Hydra's sequential launcher, with the jobs that differ only in ``seed`` run as populations.

Hydra finds launchers in the ``hydra_plugins`` namespace package only, so this module
is the plugin's shim; what it does lives in :mod:`torchrl_mbe.app.sweeps`.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

from hydra._internal.core_plugins.basic_launcher import BasicLauncher
from hydra.core.utils import JobReturn

from torchrl_mbe.app.sweeps import group_seeds, trains_together

log = logging.getLogger(__name__)


class PopulationLauncher(BasicLauncher):
    """Runs a sweep's jobs one after another, each run of consecutive seeds with all else equal as one ``population=N`` job."""

    def launch(self, job_overrides: Sequence[Sequence[str]], initial_job_idx: int) -> Sequence[JobReturn]:
        jobs = group_seeds(job_overrides, can_group=self._trains_together)
        log.info(
            f"hydra/launcher=population: {len(job_overrides)} runs as {len(jobs)} jobs (consecutive seeds as populations)"
        )
        return super().launch(jobs, initial_job_idx)

    def _trains_together(self, overrides: list[str]) -> bool:
        return trains_together(self.hydra_context.config_loader.load_sweep_config(self.config, overrides))
