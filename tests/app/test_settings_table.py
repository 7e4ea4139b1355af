"""docs/usage.md's table of settings, the library's defaults beside the app's per task, is what the config composes.

``python tests/app/test_settings_table.py`` prints the table to paste between the page's markers.
"""

from __future__ import annotations

import inspect
import re
from pathlib import Path

from hydra import compose, initialize_config_dir
from omegaconf import DictConfig

from torchrl_mbe import DynamicsModel, ModelBasedExplorationPolicy, RollingGaussianDensity
from torchrl_mbe.app import register_configs
from torchrl_mbe.app.environments import config_observation_spec
from torchrl_mbe.app.observation import match_observation

REPO = Path(__file__).resolve().parents[2]
USAGE = REPO / "docs" / "usage.md"
ENVS = ("mountaincar", "acrobot", "cartpole", "lunarlander", "deepsea", "minigrid", "gym")
MARKERS = ("<!-- settings table: tests/app/test_settings_table.py -->", "<!-- end of the settings table -->")


def _default(component: type, parameter: str):
    return inspect.signature(component.__init__).parameters[parameter].default


def _layers(cells) -> str:
    return "x".join(str(cell) for cell in cells)


ROWS = {
    # row: (the library's default, the app's setting as read from a composed config)
    "Q-network hidden layers": ("yours (README: 64x64)", lambda cfg: _layers(cfg.algo.num_cells)),
    "Q lr, gamma, n-step returns": (
        "yours (TorchRL's DQNLoss)",
        lambda cfg: f"{cfg.algo.lr:g}, {cfg.algo.gamma:g}, {cfg.algo.n_steps}",
    ),
    "Q batch, updates a frame, target copy every": (
        "yours",
        lambda cfg: f"{cfg.algo.batch_size}, {cfg.algo.updates_per_frame:g}, {cfg.algo.hard_update_interval} updates",
    ),
    "Q input standardized": ("yours", lambda cfg: "yes" if cfg.algo.standardize_inputs else "no"),
    "eps: end, over frames": (
        f"{_default(ModelBasedExplorationPolicy, 'eps_end'):g}, {_default(ModelBasedExplorationPolicy, 'annealing_num_steps')}",
        lambda cfg: f"{cfg.algo.eps_end:g}, {cfg.algo.eps_annealing_frames}",
    ),
    "envs x frames a batch": ("yours", lambda cfg: f"{cfg.env.num_envs} x {cfg.collector.frames_per_batch}"),
    "explorer, window": (
        f"RollingGaussianDensity, {_default(RollingGaussianDensity, 'window')}",
        lambda cfg: f"{cfg.exploration.name}, {cfg.exploration.get('window', '–') or 'every state'}",
    ),
    "dynamics: layers, output, prior": (
        f"{_layers(_default(DynamicsModel, 'num_cells'))}, {_default(DynamicsModel, 'output')}, none",
        lambda cfg: (
            f"{_layers(cfg.dynamics.num_cells)}, {cfg.dynamics.output}, "
            + (
                f"{_layers(cfg.dynamics.prior_num_cells or cfg.dynamics.num_cells)} x {cfg.dynamics.prior_scale:g}"
                if cfg.dynamics.prior_scale
                else "none"
            )
        ),
    ),
    "dynamics: lr, batch, updates a frame": (
        "yours (README: 1e-3, 64, 1)",
        lambda cfg: f"{cfg.dynamics.lr:g}, {cfg.dynamics.batch_size}, {cfg.dynamics.updates_per_frame:g}",
    ),
    "budget": (
        "yours",
        lambda cfg: f"{cfg.train.max_frames:,} frames" if cfg.train.max_frames else f"{cfg.train.episodes:,} episodes",
    ),
    "greedy evaluation: every, episodes": (
        "yours",
        lambda cfg: f"{cfg.eval.every_frames:,} frames, {cfg.eval.episodes}",
    ),
}


def app_config(env: str) -> DictConfig:
    """``python train.py env=<env>`` as it trains: composed, then matched to its observation."""
    register_configs()
    with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
        cfg = compose("config", overrides=[f"env={env}"])
    match_observation(cfg, config_observation_spec(cfg), named=set())
    return cfg


def render_table() -> str:
    configs = {env: app_config(env) for env in ENVS}
    names = {env: f"{env} ({configs[env].env.name})" if env in ("gym", "minigrid") else env for env in ENVS}
    lines = [
        "| setting | library default | " + " | ".join(names[env] for env in ENVS) + " |",
        "|" + "---|" * (len(ENVS) + 2),
    ]
    for row, (library, read) in ROWS.items():
        lines.append(f"| {row} | {library} | " + " | ".join(read(configs[env]) for env in ENVS) + " |")
    return "\n".join(lines)


def test_the_usage_pages_settings_table_is_what_the_config_composes():
    page = USAGE.read_text()
    documented = re.search(re.escape(MARKERS[0]) + r"\n(.*?)\n" + re.escape(MARKERS[1]), page, flags=re.DOTALL)
    assert documented is not None, f"docs/usage.md lacks the markers {MARKERS}"
    assert documented.group(1) == render_table(), "regenerate it: python tests/app/test_settings_table.py"


if __name__ == "__main__":
    print(render_table())
