"""Plain reference of the default training run: DQN with model-based exploration, no TorchRL.

One file of PyTorch + gymnasium + numpy that does what ``python train.py`` does with the
default config (MountainCar-v0, double DQN on n-step returns, Huber loss, hard target
updates, Q inputs standardized with replay statistics, and the Gou & Liu exploring rule:
go to the predicted next state least likely under a Gaussian fitted to the last 50
visited states), so that its frames/s can be compared with the TorchRL app's.

    python bench/plain_reference.py --exploration gaussian --num-envs 1 --max-frames 20000 \
        --n-steps 3 --seed 0 --eval-episodes 0     # prints one line of JSON

Every field of :class:`PlainConfig` is a flag (``--field-name``). From Python::

    from plain_reference import PlainConfig, run
    run(PlainConfig(max_frames=3000))
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
from collections import deque

import gymnasium as gym
import numpy as np
import torch
import torch.nn.functional as F
from gymnasium.vector import AutoresetMode
from torch import nn


@dataclasses.dataclass
class PlainConfig:
    """The project's default training config, flattened."""

    env_id: str = "MountainCar-v0"
    num_envs: int = 1
    exploration: str = "gaussian"  # gaussian (Gou & Liu) | egreedy (uniform exploring actions)
    max_frames: int = 20_000
    frames_per_batch: int = 16
    n_steps: int = 3
    gamma: float = 0.99
    hidden_size: int = 64  # Q-network: two hidden layers of this width
    dynamics_hidden_size: int = 64  # dynamics model: two hidden layers of this width
    q_lr: float = 2e-3
    batch_size: int = 256
    max_grad_norm: float = 10.0
    target_update_interval: int = 250
    buffer_size: int = 100_000
    learning_starts: int = 1000
    updates_per_frame: float = 0.25
    eps_init: float = 1.0
    eps_end: float = 0.05
    eps_annealing_frames: int = 20_000
    window: int = 50
    min_variance: float = 1e-8
    min_correlation_eigenvalue: float = 1e-6
    dynamics_lr: float = 1e-3
    dynamics_batch_size: int = 256
    dynamics_learning_starts: int = 256
    dynamics_updates_per_frame: float = 0.25
    seed: int = 0
    eval_episodes: int = 0
    torch_threads: int = 1


def mlp(in_size: int, out_size: int, hidden_size: int) -> nn.Sequential:
    """Two ReLU hidden layers, Xavier-uniform weights, zero biases."""
    net = nn.Sequential(
        nn.Linear(in_size, hidden_size),
        nn.ReLU(),
        nn.Linear(hidden_size, hidden_size),
        nn.ReLU(),
        nn.Linear(hidden_size, out_size),
    )
    for layer in net:
        if isinstance(layer, nn.Linear):
            nn.init.xavier_uniform_(layer.weight)
            nn.init.zeros_(layer.bias)
    return net


def mean_std(samples: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-feature mean and unbiased std (floored at 1e-6) of ``samples``."""
    data = torch.as_tensor(samples)
    return data.mean(0), data.std(0).clamp_min(1e-6)


class QNetwork(nn.Module):
    """Q-values of standardized observations."""

    def __init__(self, obs_dim: int, num_actions: int, hidden_size: int) -> None:
        super().__init__()
        self.net = mlp(obs_dim, num_actions, hidden_size)
        self.register_buffer("obs_mean", torch.zeros(obs_dim))
        self.register_buffer("obs_std", torch.ones(obs_dim))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.net((obs - self.obs_mean) / self.obs_std)


class DynamicsModel(nn.Module):
    """D(s, a): predicts the next observation through the standardized delta ``s' - s``."""

    def __init__(self, obs_dim: int, num_actions: int, hidden_size: int) -> None:
        super().__init__()
        self.num_actions = num_actions
        self.net = mlp(obs_dim + num_actions, obs_dim, hidden_size)
        for name in ("obs_mean", "delta_mean"):
            self.register_buffer(name, torch.zeros(obs_dim))
        for name in ("obs_std", "delta_std"):
            self.register_buffer(name, torch.ones(obs_dim))

    def forward(self, obs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        one_hot = F.one_hot(action, self.num_actions).to(obs.dtype)
        inputs = torch.cat([(obs - self.obs_mean) / self.obs_std, one_hot], -1)
        return obs + self.delta_mean + self.delta_std * self.net(inputs)


class ReplayBuffer:
    """Uniform replay of n-step transitions, each with its 1-step next observation for D."""

    FIELDS = ("obs", "action", "next_obs", "ret", "bootstrap_obs", "bootstrap_discount")

    def __init__(self, capacity: int, obs_dim: int) -> None:
        self.capacity, self.size, self.cursor = capacity, 0, 0
        self.obs = np.zeros((capacity, obs_dim), np.float32)
        self.action = np.zeros(capacity, np.int64)
        self.next_obs = np.zeros((capacity, obs_dim), np.float32)
        self.ret = np.zeros(capacity, np.float32)
        self.bootstrap_obs = np.zeros((capacity, obs_dim), np.float32)
        self.bootstrap_discount = np.zeros(capacity, np.float32)

    def add(self, transition: tuple) -> None:
        """Stores ``transition``, one value per name of :attr:`FIELDS`, over the oldest when full."""
        for name, value in zip(self.FIELDS, transition):
            getattr(self, name)[self.cursor] = value
        self.cursor = (self.cursor + 1) % self.capacity
        self.size = min(self.size + 1, self.capacity)

    def sample(self, batch_size: int, rng: np.random.Generator) -> dict[str, torch.Tensor]:
        index = rng.integers(self.size, size=batch_size)
        return {name: torch.from_numpy(getattr(self, name)[index]) for name in self.FIELDS}


class NStepAccumulator:
    """Turns one env's stream of 1-step transitions into n-step ones, cut at episode ends."""

    def __init__(self, n_steps: int, gamma: float) -> None:
        self.n_steps, self.gamma = n_steps, gamma
        self.pending: deque[tuple] = deque()

    def push(
        self, obs: np.ndarray, action: int, reward: float, next_obs: np.ndarray, terminated: bool, truncated: bool
    ) -> list[tuple]:
        """Adds one step; returns the transitions it completes (all pending ones at an episode end)."""
        self.pending.append((obs, action, reward, next_obs))
        if terminated or truncated:
            return [self._pop_front(terminated) for _ in range(len(self.pending))]
        return [self._pop_front(False)] if len(self.pending) == self.n_steps else []

    def _pop_front(self, terminated: bool) -> tuple:
        """(s, a, s', sum_k gamma^k r_k, s_boot, gamma^k or 0 if terminated) for the oldest pending step."""
        obs, action, _, next_obs = self.pending[0]
        ret = sum(self.gamma**k * step[2] for k, step in enumerate(self.pending))
        discount = 0.0 if terminated else self.gamma ** len(self.pending)
        transition = (obs, action, next_obs, ret, self.pending[-1][3], discount)
        self.pending.popleft()
        return transition


def gaussian_neg_log_density(
    windows: np.ndarray, points: np.ndarray, min_variance: float, min_eig: float
) -> np.ndarray:
    """-log N(points | mu, Sigma) under a Gaussian fitted to each window.

    ``windows`` (k, F, D), ``points`` (k, A, D) -> (k, A). Float64, unbiased covariance;
    variances floored at ``min_variance``, correlation eigenvalues at ``min_eig``.
    """
    loc = windows.mean(1)
    centered = windows - loc[:, None]
    covariance = centered.transpose(0, 2, 1) @ centered / max(windows.shape[1] - 1, 1)
    std = np.sqrt(np.maximum(np.diagonal(covariance, axis1=1, axis2=2), min_variance))
    eigenvalues, eigenvectors = np.linalg.eigh(covariance / (std[:, :, None] * std[:, None, :]))
    eigenvalues = np.maximum(eigenvalues, min_eig)
    # Sigma = S V L V^T S, so the whitened point is L^-1/2 V^T S^-1 (x - mu).
    whitened = ((points - loc[:, None]) / std[:, None]) @ eigenvectors / np.sqrt(eigenvalues)[:, None]
    log_det = np.log(eigenvalues).sum(-1) + 2 * np.log(std).sum(-1)
    log_normalizer = 0.5 * (log_det + windows.shape[2] * math.log(2 * math.pi))
    return 0.5 * np.square(whitened).sum(-1) + log_normalizer[:, None]


def random_argmax(scores: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Argmax over the last axis, ties broken uniformly at random."""
    is_best = scores == scores.max(-1, keepdims=True)
    return (rng.random(scores.shape) * is_best).argmax(-1)


class Agent:
    """Q-network, target network, dynamics model (gaussian only), novelty windows and optimizers."""

    def __init__(self, cfg: PlainConfig, obs_dim: int, num_actions: int, rng: np.random.Generator) -> None:
        self.cfg, self.num_actions, self.rng = cfg, num_actions, rng
        self.q = QNetwork(obs_dim, num_actions, cfg.hidden_size)
        self.target = QNetwork(obs_dim, num_actions, cfg.hidden_size)
        self.target.load_state_dict(self.q.state_dict())
        self.q_optimizer = torch.optim.Adam(self.q.parameters(), lr=cfg.q_lr, fused=True)
        self.q_updates = self.dynamics_updates = 0
        self.dynamics = None
        if cfg.exploration == "gaussian":
            self.dynamics = DynamicsModel(obs_dim, num_actions, cfg.dynamics_hidden_size)
            self.dynamics_optimizer = torch.optim.Adam(self.dynamics.parameters(), lr=cfg.dynamics_lr, fused=True)
            self.windows = np.zeros((cfg.num_envs, cfg.window, obs_dim), np.float64)
            self.visited = 0

    @torch.no_grad()
    def greedy(self, obs: np.ndarray) -> np.ndarray:
        return self.q(torch.from_numpy(obs)).argmax(-1).numpy()

    def act(self, obs: np.ndarray, eps: float) -> np.ndarray:
        """Epsilon-greedy over envs; every observation acted on enters its env's novelty window."""
        actions = self.greedy(obs)
        if self.dynamics is not None:
            self.windows[:, self.visited % self.cfg.window] = obs
            self.visited += 1
        explore = self.rng.random(len(obs)) < eps
        if explore.any():
            actions[explore] = self.exploring_actions(obs[explore], explore)
        return actions

    def exploring_actions(self, obs: np.ndarray, envs: np.ndarray) -> np.ndarray:
        """Uniform (egreedy), or the action whose predicted next state is rarest under its env's window (gaussian).

        The Gaussian is fitted here, on exploring steps only (every step changes the window).
        """
        if self.dynamics is None:
            return self.rng.integers(self.num_actions, size=len(obs))
        k, actions = len(obs), torch.arange(self.num_actions)
        with torch.no_grad():
            repeated = torch.from_numpy(obs).repeat_interleave(self.num_actions, 0)
            predicted = self.dynamics(repeated, actions.repeat(k)).reshape(k, self.num_actions, -1)
        windows = self.windows[envs, : min(self.visited, self.cfg.window)]
        scores = gaussian_neg_log_density(
            windows, predicted.double().numpy(), self.cfg.min_variance, self.cfg.min_correlation_eigenvalue
        )
        return random_argmax(scores, self.rng)

    def update_q(self, buffer: ReplayBuffer) -> None:
        """One double-DQN step on n-step targets; the first fits the input statistics; hard target copies."""
        if self.q_updates == 0:
            self.q.obs_mean, self.q.obs_std = mean_std(buffer.obs[: buffer.size])
            self.target.load_state_dict(self.q.state_dict())
        batch = buffer.sample(self.cfg.batch_size, self.rng)
        q_taken = self.q(batch["obs"]).gather(1, batch["action"][:, None]).squeeze(1)
        with torch.no_grad():
            best_next = self.q(batch["bootstrap_obs"]).argmax(-1, keepdim=True)
            next_value = self.target(batch["bootstrap_obs"]).gather(1, best_next).squeeze(1)
            target = batch["ret"] + batch["bootstrap_discount"] * next_value
        optimizer_step(F.smooth_l1_loss(q_taken, target), self.q_optimizer, self.cfg.max_grad_norm)
        self.q_updates += 1
        if self.q_updates % self.cfg.target_update_interval == 0:
            self.target.load_state_dict(self.q.state_dict())

    def update_dynamics(self, buffer: ReplayBuffer) -> None:
        """One step of D on 1-step transitions, MSE in delta-std units; the first fits D's statistics."""
        model = self.dynamics
        if self.dynamics_updates == 0:
            obs, next_obs = buffer.obs[: buffer.size], buffer.next_obs[: buffer.size]
            model.obs_mean, model.obs_std = mean_std(obs)
            model.delta_mean, model.delta_std = mean_std(next_obs - obs)
        batch = buffer.sample(self.cfg.dynamics_batch_size, self.rng)
        error = (model(batch["obs"], batch["action"]) - batch["next_obs"]) / model.delta_std
        optimizer_step(error.square().mean(), self.dynamics_optimizer, self.cfg.max_grad_norm)
        self.dynamics_updates += 1


def optimizer_step(loss: torch.Tensor, optimizer: torch.optim.Optimizer, max_grad_norm: float) -> None:
    """Backward, gradient-norm clipping, Adam step."""
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    for group in optimizer.param_groups:
        nn.utils.clip_grad_norm_(group["params"], max_grad_norm)
    optimizer.step()


def epsilon(cfg: PlainConfig, frames: int) -> float:
    """Linear from eps_init to eps_end over eps_annealing_frames frames counted from learning_starts."""
    progress = max(frames - cfg.learning_starts, 0) / cfg.eps_annealing_frames
    return max(cfg.eps_end, cfg.eps_init - (cfg.eps_init - cfg.eps_end) * progress)


@dataclasses.dataclass
class Progress:
    """Loop counters and the update credits that frames pay into."""

    frames: int = 0
    episodes: int = 0
    first_success_episode: int | None = None
    q_credit: float = 0.0
    dynamics_credit: float = 0.0


def collect_step(
    envs: gym.vector.VectorEnv,
    obs: np.ndarray,
    agent: Agent,
    eps: float,
    accumulators: list[NStepAccumulator],
    buffer: ReplayBuffer,
    progress: Progress,
) -> np.ndarray:
    """Steps every env once, stores the completed n-step transitions, counts ended episodes."""
    actions = agent.act(obs, eps)
    next_obs, rewards, terminated, truncated, info = envs.step(actions)
    for i, accumulator in enumerate(accumulators):
        ended = terminated[i] or truncated[i]
        final_obs = info["final_obs"][i] if ended else next_obs[i]  # same-step autoreset: next_obs[i] is a reset
        for transition in accumulator.push(obs[i], actions[i], rewards[i], final_obs, terminated[i], truncated[i]):
            buffer.add(transition)
        if ended:
            progress.episodes += 1
            if terminated[i] and progress.first_success_episode is None:
                progress.first_success_episode = progress.episodes
    return next_obs.astype(np.float32, copy=False)


def train_on_new_frames(
    cfg: PlainConfig, new_frames: int, agent: Agent, buffer: ReplayBuffer, progress: Progress
) -> None:
    """The dynamics and Q updates that ``new_frames`` frames pay for."""
    if agent.dynamics is not None and progress.frames >= cfg.dynamics_learning_starts:
        progress.dynamics_credit += new_frames * cfg.dynamics_updates_per_frame
        while progress.dynamics_credit >= 1:
            agent.update_dynamics(buffer)
            progress.dynamics_credit -= 1
    if progress.frames < cfg.learning_starts:
        return
    progress.q_credit += new_frames * cfg.updates_per_frame
    while progress.q_credit >= 1:
        agent.update_q(buffer)
        progress.q_credit -= 1


def evaluate(agent: Agent, cfg: PlainConfig) -> float | None:
    """Mean return of ``eval_episodes`` greedy episodes on a separate env; None when 0."""
    if cfg.eval_episodes == 0:
        return None
    env, returns = gym.make(cfg.env_id), []
    for episode in range(cfg.eval_episodes):
        obs, _ = env.reset(seed=cfg.seed + 10_000 if episode == 0 else None)
        total, ended = 0.0, False
        while not ended:
            obs, reward, terminated, truncated, _ = env.step(int(agent.greedy(obs[None].astype(np.float32))[0]))
            total, ended = total + float(reward), terminated or truncated
        returns.append(total)
    return float(np.mean(returns))


def run(cfg: PlainConfig) -> dict:
    """Trains for ``max_frames`` frames; frames/s counts the loop only (not setup, not evaluation)."""
    if cfg.exploration not in ("gaussian", "egreedy"):
        raise ValueError(f"exploration must be 'gaussian' or 'egreedy', got {cfg.exploration!r}.")
    if cfg.frames_per_batch % cfg.num_envs:
        raise ValueError(f"frames_per_batch ({cfg.frames_per_batch}) must be a multiple of num_envs ({cfg.num_envs}).")
    torch.set_num_threads(cfg.torch_threads)
    torch.set_flush_denormal(True)  # as train(cfg) does: subnormal Adam moments slow the CPU down
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    envs = gym.vector.SyncVectorEnv(
        [lambda: gym.make(cfg.env_id)] * cfg.num_envs, autoreset_mode=AutoresetMode.SAME_STEP
    )
    obs_dim, num_actions = envs.single_observation_space.shape[0], int(envs.single_action_space.n)
    agent = Agent(cfg, obs_dim, num_actions, rng)
    buffer = ReplayBuffer(cfg.buffer_size, obs_dim)
    accumulators = [NStepAccumulator(cfg.n_steps, cfg.gamma) for _ in range(cfg.num_envs)]
    progress = Progress()
    obs = envs.reset(seed=cfg.seed)[0].astype(np.float32, copy=False)
    started = time.perf_counter()
    while progress.frames < cfg.max_frames:
        eps = epsilon(cfg, progress.frames)
        for _ in range(cfg.frames_per_batch // cfg.num_envs):
            obs = collect_step(envs, obs, agent, eps, accumulators, buffer, progress)
        progress.frames += cfg.frames_per_batch
        train_on_new_frames(cfg, cfg.frames_per_batch, agent, buffer, progress)
    wall_time = time.perf_counter() - started
    envs.close()
    return {
        "frames": progress.frames,
        "wall_time_s": round(wall_time, 3),
        "frames_per_s": round(progress.frames / wall_time, 1),
        "q_updates": agent.q_updates,
        "dynamics_updates": agent.dynamics_updates,
        "final_eval_return": evaluate(agent, cfg),
        "episodes": progress.episodes,
        "first_success_episode": progress.first_success_episode,
    }


def parse_config(argv: list[str] | None = None) -> PlainConfig:
    """A ``--field-name`` flag for every :class:`PlainConfig` field, typed by its default."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    for field in dataclasses.fields(PlainConfig):
        parser.add_argument("--" + field.name.replace("_", "-"), type=type(field.default), default=field.default)
    return PlainConfig(**vars(parser.parse_args(argv)))


if __name__ == "__main__":
    print(json.dumps(run(parse_config())))
