"""Train DQN with model-based exploration: ``python train.py env=mountaincar exploration=gaussian``.

A thin Hydra wrapper around :func:`torchrl_mbe.app.train`; the config lives in ``conf/``.
Sweeps: ``python train.py -m exploration=gaussian,kernel,egreedy seed=0,1,2``.
"""

from __future__ import annotations

import json
import logging
import sys

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from torchrl_mbe.app import ConfigError, register_configs, summary_line, train
from torchrl_mbe.app.config import with_env_group

log = logging.getLogger("train")


@hydra.main(config_path="conf", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> float | None:
    try:
        summary = train(cfg)
    except ConfigError as error:
        raise SystemExit(f"Error: {error}") from None
    log.info("Summary:\n%s", json.dumps(summary, indent=2))
    members = summary.get("members", [summary])  # population=M: one summary per member
    run_dirs = summary.get("run_dirs", [HydraConfig.get().runtime.output_dir])
    for member, run_dir in zip(members, run_dirs):
        log.info(summary_line(member, run_dir))  # the last lines: solved?, time, where
    return summary["final_eval_return"]


if __name__ == "__main__":
    register_configs()  # conf/config.yaml extends the schema's base_config
    sys.argv[1:] = with_env_group(sys.argv[1:])  # env.name=X alone: X's conf/env/ file, else env=gym
    main()
