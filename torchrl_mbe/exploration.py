"""The exploration policy: a greedy Q-value actor whose exploring steps are planned."""
from __future__ import annotations

from typing import Literal

import torch
from tensordict import NestedKey, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from tensordict.utils import expand_as_right
from torchrl.data import TensorSpec
from torchrl.envs.utils import ExplorationType, exploration_type
from torchrl.modules import EGreedyModule

from torchrl_mbe.planner import NoveltyPlanner

__all__ = ["AnnealedEGreedyModule", "ModelBasedExplorationPolicy", "anneal_eps"]


class ModelBasedExplorationPolicy(TensorDictModuleBase):
    """Epsilon-greedy policy whose exploring steps go to the rarest predicted state.

    "DQN with Model-Based Exploration" (Gou & Liu): with probability ``eps`` a batch
    element explores and takes the :class:`~torchrl_mbe.NoveltyPlanner`'s action,
    otherwise the actor's greedy action. It follows TorchRL's
    :class:`~torchrl.modules.EGreedyModule`:

    * it explores only under ``ExplorationType.RANDOM`` (or when none is set); under
      ``DETERMINISTIC`` (evaluation) it is exactly ``actor`` and leaves the novelty
      window untouched;
    * ``eps`` is a buffer and :meth:`step` anneals it, linearly (as ``EGreedyModule``)
      or multiplicatively (the paper: ``eps *= decay`` per step, with ``decay``
      chosen so that ``eps_end`` is reached after ``annealing_num_steps`` steps);
    * every visited observation is pushed into the planner's novelty window before
      planning, so after a rollout the window holds the last F visited states.

    Optional warm-up (the original code only trusted its model once the prediction
    error fell below a threshold): with ``model_error_threshold`` set, exploring
    steps take uniformly random actions until :meth:`report_model_error` receives an
    error at or below the threshold; from then on the planner decides.

    Keep the policy on the collector's device: a :class:`~torchrl.collectors.Collector`
    that has to move the policy works on a copy and syncs buffers from this module,
    which would overwrite the window the copy filled.

    Args:
        actor (TensorDictModuleBase): greedy actor, e.g. :class:`~torchrl.modules.QValueActor`.
        planner (NoveltyPlanner): proposes exploring actions.
        eps_init (float): initial exploration probability. Defaults to 1.0.
        eps_end (float): final exploration probability. Defaults to 0.01 (the paper).
        annealing_num_steps (int): steps for eps to reach ``eps_end``. Defaults to 10_000.

    Keyword Args:
        schedule (str): ``"linear"`` or ``"exponential"``. Defaults to ``"linear"``.
        model_error_threshold (float, optional): enables the random warm-up.
        action_key (NestedKey): the action entry. Defaults to ``"action"``.

    Examples:
        >>> import torch
        >>> from torchrl.envs import GymEnv
        >>> from torchrl.modules import MLP, QValueActor
        >>> from torchrl_mbe import DynamicsModel, ModelBasedExplorationPolicy, NoveltyPlanner, RollingGaussianDensity
        >>> env = GymEnv("MountainCar-v0")
        >>> actor = QValueActor(MLP(out_features=3, num_cells=[48]), spec=env.action_spec, in_keys=["observation"])
        >>> planner = NoveltyPlanner(DynamicsModel(2, env.action_spec), RollingGaussianDensity(2, window=50), env.action_spec)
        >>> policy = ModelBasedExplorationPolicy(actor, planner, eps_init=1.0, eps_end=0.01, annealing_num_steps=1000)
        >>> rollout = env.rollout(20, policy)
        >>> planner.novelty.num_stored
        20
        >>> policy.step(500); round(policy.eps.item(), 3)
        0.505
    """

    def __init__(
        self,
        actor: TensorDictModuleBase,
        planner: NoveltyPlanner,
        eps_init: float = 1.0,
        eps_end: float = 0.01,
        annealing_num_steps: int = 10_000,
        *,
        schedule: Literal["linear", "exponential"] = "linear",
        model_error_threshold: float | None = None,
        action_key: NestedKey = "action",
    ) -> None:
        super().__init__()
        _check_schedule(eps_init, eps_end, annealing_num_steps, schedule)
        self.actor = actor
        self.planner = planner
        self.schedule = schedule
        self.annealing_num_steps = int(annealing_num_steps)
        self.model_error_threshold = model_error_threshold
        self.action_key = action_key
        self.observation_key = planner.in_keys[0]
        self.in_keys = list(dict.fromkeys([*actor.in_keys, self.observation_key]))
        self.out_keys = list(actor.out_keys)
        device = planner.candidate_actions.device
        self.register_buffer("eps_init", torch.tensor(float(eps_init), device=device))
        self.register_buffer("eps_end", torch.tensor(float(eps_end), device=device))
        self.register_buffer("eps", torch.tensor(float(eps_init), device=device))
        self.register_buffer("model_trusted", torch.tensor(model_error_threshold is None, device=device))

    @property
    def novelty(self):
        """The planner's novelty scorer (its window holds the visited states)."""
        return self.planner.novelty

    def step(self, frames: int = 1) -> None:
        """Anneals eps by ``frames`` steps of the schedule (no-op once at ``eps_end``)."""
        anneal_eps(self, frames)

    def report_model_error(self, error: float) -> bool:
        """Feeds the dynamics model's current prediction error to the warm-up switch.

        Returns whether the planner is trusted from now on (always ``True``
        without ``model_error_threshold``; once trusted, it stays trusted).
        """
        if self.model_error_threshold is not None and error <= self.model_error_threshold:
            self.model_trusted.fill_(True)
        return bool(self.model_trusted)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        tensordict = self.actor(tensordict)
        if exploration_type() not in (ExplorationType.RANDOM, None):
            return tensordict
        self.novelty.update(tensordict.get(self.observation_key))
        explore = torch.rand(tensordict.batch_size, device=self.eps.device) < self.eps
        if explore.any():
            greedy = tensordict.get(self.action_key)
            exploring = self._exploring_action(tensordict).to(greedy.dtype)
            tensordict.set(self.action_key, torch.where(expand_as_right(explore, greedy), exploring, greedy))
        return tensordict

    def _exploring_action(self, tensordict: TensorDictBase) -> torch.Tensor:
        candidates = self.planner.candidate_actions
        if not self.model_trusted:
            return candidates[torch.randint(len(candidates), tensordict.batch_size, device=candidates.device)]
        planned = self.planner(tensordict.select(self.observation_key))
        return planned.get(self.planner.out_keys[0])


class AnnealedEGreedyModule(EGreedyModule):
    """TorchRL's :class:`~torchrl.modules.EGreedyModule` with a choice of schedule.

    The plain-DQN baseline: random exploring actions, annealed exactly as
    :class:`ModelBasedExplorationPolicy` anneals, so that only the exploring
    rule differs between the two. ``schedule="linear"`` is ``EGreedyModule``.

    Examples:
        >>> from torchrl.data import OneHot
        >>> from torchrl_mbe.exploration import AnnealedEGreedyModule
        >>> module = AnnealedEGreedyModule(OneHot(3), 1.0, 0.01, 9209, schedule="exponential")
        >>> module.step(1); round(module.eps.item(), 4)
        0.9995
    """

    def __init__(
        self,
        spec: TensorSpec,
        eps_init: float = 1.0,
        eps_end: float = 0.01,
        annealing_num_steps: int = 10_000,
        *,
        schedule: Literal["linear", "exponential"] = "linear",
        action_key: NestedKey = "action",
    ) -> None:
        _check_schedule(eps_init, eps_end, annealing_num_steps, schedule)
        super().__init__(spec, float(eps_init), eps_end, int(annealing_num_steps), action_key=action_key)
        self.schedule = schedule

    def step(self, frames: int = 1) -> None:
        """Anneals eps by ``frames`` steps of the schedule (no-op once at ``eps_end``)."""
        anneal_eps(self, frames)


def anneal_eps(module: torch.nn.Module, frames: int) -> None:
    """Advances ``module.eps`` by ``frames`` steps of its linear or exponential schedule.

    ``module`` has ``eps``/``eps_init``/``eps_end`` buffers and ``schedule`` and
    ``annealing_num_steps`` attributes; eps never goes below ``eps_end``.
    """
    if module.schedule == "linear":
        annealed = module.eps - frames * (module.eps_init - module.eps_end) / module.annealing_num_steps
    else:
        decay = (module.eps_end / module.eps_init) ** (1.0 / module.annealing_num_steps)
        annealed = module.eps * decay**frames
    module.eps.copy_(torch.maximum(module.eps_end, annealed).to(module.eps.dtype))


def _check_schedule(eps_init: float, eps_end: float, annealing_num_steps: int, schedule: str) -> None:
    if not 0.0 <= eps_end <= eps_init <= 1.0:
        raise ValueError(f"Expected 0 <= eps_end <= eps_init <= 1, got eps_init={eps_init}, eps_end={eps_end}.")
    if int(annealing_num_steps) < 1:
        raise ValueError(f"annealing_num_steps must be >= 1, got {annealing_num_steps}.")
    if schedule not in ("linear", "exponential"):
        raise ValueError(f"schedule must be 'linear' or 'exponential', got {schedule!r}.")
    if schedule == "exponential" and eps_end <= 0.0:
        raise ValueError("The exponential schedule needs eps_end > 0 (it decays multiplicatively).")

