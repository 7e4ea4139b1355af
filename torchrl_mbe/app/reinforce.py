"""REINFORCE (Monte Carlo policy gradient): the paper's policy-gradient baseline, ``algo=reinforce``.

Gou & Liu compare their agent with the REINFORCE of Morvan Zhou's tutorial
("Reinforcement learning methods and tutorials"), with the hyper-parameters of
their appendix (Table 2): a policy network of one hidden layer of 10 tanh units
and a linear layer to the action logits (weights ``N(0, 0.3)``, biases 0.1),
Adam with learning rate 0.02, discount 0.995.

The agent plays one whole episode with its stochastic policy (that sampling is
all its exploration: no eps), then takes one gradient step on it:

* the discounted return-to-go ``G_t`` of every step (TorchRL's ``reward2go``);
  an episode cut by the time limit counts as ended, as in the tutorial;
* the advantage is ``G_t`` normalized over the episode, ``(G_t - mean) / std``,
  as the tutorial does: it centres the returns (a crude baseline) and scales
  every episode's step to the same size;
* the loss is TorchRL's :class:`~torchrl.objectives.ReinforceLoss`,
  ``mean_t(-log pi(a_t | s_t) * advantage_t)``.

``ReinforceLoss`` always pairs the policy with a critic (it raises without one,
and computes a critic loss on every call). Plain REINFORCE is REINFORCE with the
baseline ``V(s) = 0``, so the critic here is that constant: no parameters, and
its ``loss_value`` is neither optimized nor logged. The advantage is written
into each episode under the loss's advantage key, so the loss never runs its
value estimator.

:func:`train_reinforce` is the training loop; it shares the DQN app's run bookkeeping
(:mod:`torchrl_mbe.app.population`, with one member), its run
directory layout (``episodes.csv`` with ``eps`` 0, ``evaluations.csv``,
``summary.json`` with method ``reinforce``), its greedy evaluation (the mode of
the policy under ``ExplorationType.DETERMINISTIC``), checkpoints (policy and
optimizer) with ``resume=true``, and Ctrl-C handling.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import torch
from omegaconf import DictConfig
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.data import TensorSpec
from torchrl.envs import EnvBase, ExplorationType, set_exploration_type
from torchrl.modules import OneHotCategorical, ProbabilisticActor
from torchrl.objectives import ReinforceLoss
from torchrl.objectives.value.functional import reward2go

from torchrl_mbe.app.environments import make_run_env
from torchrl_mbe.app.evaluation import play_episode
from torchrl_mbe.app.optim import GradientStep, adam
from torchrl_mbe.app.population import StopOnInterrupt, open_population
from torchrl_mbe.app.rollout import EnvState
from torchrl_mbe.modules import make_per_action_mlp

__all__ = [
    "ReinforceAgent",
    "build_reinforce_agent",
    "make_policy_actor",
    "train_reinforce",
    "update_policy",
    "write_advantage",
]


@dataclass
class ReinforceAgent:
    """Everything a REINFORCE run trains, saves and restores."""

    actor: ProbabilisticActor
    loss: ReinforceLoss
    step: GradientStep  # ReinforceLoss on a whole episode, Adam
    gamma: float

    def summary_fields(self) -> dict[str, int]:
        """Nothing beyond the run's own counters: its one policy update per episode is counted as episodes."""
        return {}

    def state_dict(self) -> dict:
        return {"actor": self.actor.state_dict(), "optimizer": self.step.optimizer.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        self.actor.load_state_dict(state["actor"])
        self.step.optimizer.load_state_dict(state["optimizer"])


def make_policy_actor(
    observation_size: int,
    action_spec: TensorSpec,
    num_cells: Sequence[int],
    *,
    weight_std: float = 0.3,
    bias_init: float = 0.1,
    device: torch.device | str = "cpu",
) -> ProbabilisticActor:
    """A categorical policy: ``MLP`` (tanh) -> ``logits`` -> ``OneHotCategorical`` over the one-hot ``action_spec``.

    Every layer starts with weights ``N(0, weight_std)`` and biases ``bias_init``
    (the paper's Table 2). Under ``ExplorationType.RANDOM`` the actor samples an
    action, under ``DETERMINISTIC`` it takes the most likely one. It does not
    write the action's log-probability: ``ReinforceLoss`` recomputes it from the
    stored action under the current parameters.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl.data import OneHot
        >>> from torchrl.envs import ExplorationType, set_exploration_type
        >>> from torchrl_mbe.app.reinforce import make_policy_actor
        >>> actor = make_policy_actor(2, OneHot(3), [10])
        >>> with set_exploration_type(ExplorationType.DETERMINISTIC):
        ...     step = actor(TensorDict({"observation": torch.zeros(2)}, []))
        >>> step["logits"].shape, int(step["action"].sum())
        (torch.Size([3]), 1)
    """
    network = make_per_action_mlp(
        observation_size,
        action_spec,
        num_cells,
        nn.Tanh,
        partial(nn.init.normal_, mean=0.0, std=weight_std),
        partial(nn.init.constant_, val=bias_init),
        device,
    )
    return ProbabilisticActor(
        TensorDictModule(network, in_keys=["observation"], out_keys=["logits"]),
        in_keys=["logits"],
        spec=action_spec,
        distribution_class=OneHotCategorical,
    )


def _zero_value(observation: torch.Tensor) -> torch.Tensor:
    """The baseline ``V(s) = 0``: ``ReinforceLoss``'s critic for plain REINFORCE."""
    return observation.new_zeros(*observation.shape[:-1], 1)


def build_reinforce_agent(cfg: DictConfig, env: EnvBase) -> ReinforceAgent:
    """The policy of ``cfg.algo``, ``ReinforceLoss`` with the zero baseline, and Adam."""
    device = torch.device(cfg.device)
    actor = make_policy_actor(
        env.observation_spec_unbatched["observation"].shape[-1],
        env.action_spec_unbatched.to(device),
        cfg.algo.num_cells,
        weight_std=cfg.algo.weight_std,
        bias_init=cfg.algo.bias_init,
        device=device,
    )
    zero_baseline = TensorDictModule(_zero_value, in_keys=["observation"], out_keys=["state_value"])
    loss = ReinforceLoss(actor, zero_baseline, functional=False)
    gamma = cfg.algo.gamma
    step = GradientStep(
        lambda episode: loss(write_advantage(episode, gamma))["loss_actor"], adam(actor.parameters(), cfg.algo.lr), None
    )
    return ReinforceAgent(actor, loss, step, gamma)


def write_advantage(episode: TensorDictBase, gamma: float) -> TensorDictBase:
    """Writes ``ReinforceLoss``'s inputs into one episode of shape ``(steps,)`` and returns it.

    ``value_target``: the discounted returns-to-go ``G_t``; ``advantage``: ``G_t``
    minus their mean over the episode, divided by their (population) standard
    deviation, as Morvan's tutorial normalizes them (a one-step episode gets 0).

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl_mbe.app.reinforce import write_advantage
        >>> episode = TensorDict({"next": {
        ...     "reward": torch.tensor([[0.0], [0.0], [1.0]]),
        ...     "done": torch.tensor([[False], [False], [True]])}}, [3])
        >>> write_advantage(episode, gamma=0.5)["value_target"].flatten()
        tensor([0.2500, 0.5000, 1.0000])
        >>> episode["advantage"].flatten()
        tensor([-1.0690, -0.2673,  1.3363])
    """
    returns = reward2go(episode["next", "reward"], episode["next", "done"], gamma)
    episode["value_target"] = returns
    episode["advantage"] = (returns - returns.mean()) / returns.std(correction=0).clamp_min(1e-8)
    return episode


def update_policy(agent: ReinforceAgent, episode: TensorDictBase) -> None:
    """One REINFORCE gradient step on one whole episode."""
    agent.step(episode)


def train_reinforce(cfg: DictConfig, run_dir: Path) -> dict:
    """Trains REINFORCE, one update per episode, and returns the run's summary (see :func:`~torchrl_mbe.app.train`)."""
    env = make_run_env(cfg, num_envs=1, seed=cfg.seed)
    agent = build_reinforce_agent(cfg, env)
    run = open_population(cfg, run_dir, agent)  # one run: REINFORCE trains no populations
    run.keep("env", EnvState(env))
    with StopOnInterrupt() as interrupt:
        while run.training(interrupt):
            with set_exploration_type(ExplorationType.RANDOM), torch.no_grad():
                episode = play_episode(env, agent.actor)
            run.record(episode)
            update_policy(agent, episode)
            run.evaluate_and_checkpoint_if_due(episode.numel())
    return run.finish(interrupt)
