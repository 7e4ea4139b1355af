"""Exploration policies: TorchRL's e-greedy with a choice of schedule, and its model-based variant."""

from __future__ import annotations

from typing import Literal

import torch
from tensordict import NestedKey, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from tensordict.utils import expand_as_right
from torchrl.data import Composite, TensorSpec, Unbounded
from torchrl.envs.utils import ExplorationType, exploration_type
from torchrl.modules import EGreedyModule

from torchrl_mbe.modules.networks import action_values
from torchrl_mbe.modules.planner import NoveltyPlanner, random_argmax, reachable_novelty

__all__ = ["AnnealedEGreedyModule", "ModelBasedExplorationPolicy", "check_eps_schedule"]


class AnnealedEGreedyModule(EGreedyModule):
    """TorchRL's :class:`~torchrl.modules.EGreedyModule` with a choice of schedule.

    The plain-DQN baseline, and the base of :class:`ModelBasedExplorationPolicy`:
    both anneal eps with this class's :meth:`step`, so that only the exploring
    rule differs between them. ``schedule="linear"`` is ``EGreedyModule``'s;
    ``"exponential"`` multiplies eps by a constant per step (the paper's
    ``eps *= 0.9995``), the constant chosen so that ``eps_end`` is reached after
    ``annealing_num_steps`` steps.

    Args:
        spec (TensorSpec): the action spec (random actions are drawn from it).
        eps_init (float): initial exploration probability. Defaults to 1.0.
        eps_end (float): final exploration probability. Defaults to 0.01 (the paper).
        annealing_num_steps (int): steps for eps to reach ``eps_end``. Defaults to 10_000.

    Keyword Args:
        schedule (str): ``"linear"`` or ``"exponential"``. Defaults to ``"linear"``.
        action_key (NestedKey): the action entry. Defaults to ``"action"``.
        device (torch.device, optional): where the eps buffers live.

    Examples:
        >>> from torchrl.data import OneHot
        >>> from torchrl_mbe import AnnealedEGreedyModule
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
        device: torch.device | str | None = None,
    ) -> None:
        check_eps_schedule(eps_init, eps_end, annealing_num_steps, schedule)
        super().__init__(
            spec, float(eps_init), float(eps_end), int(annealing_num_steps), action_key=action_key, device=device
        )
        self.schedule = schedule

    def step(self, frames: int = 1) -> None:
        """Anneals eps by ``frames`` steps of the schedule; eps never goes below ``eps_end``."""
        if self.schedule == "linear":
            annealed = self.eps - frames * (self.eps_init - self.eps_end) / self.annealing_num_steps
        else:
            decay = (self.eps_end / self.eps_init) ** (1.0 / self.annealing_num_steps)
            annealed = self.eps * decay**frames
        self.eps.copy_(torch.maximum(self.eps_end, annealed).to(self.eps.dtype))


class ModelBasedExplorationPolicy(AnnealedEGreedyModule):
    """Epsilon-greedy policy whose exploring steps go to the rarest predicted state.

    "DQN with Model-Based Exploration" (Gou & Liu): with probability ``eps`` a batch
    element explores and takes the :class:`~torchrl_mbe.NoveltyPlanner`'s action,
    otherwise the actor's greedy action. It follows TorchRL's
    :class:`~torchrl.modules.EGreedyModule`:

    * it explores only under ``ExplorationType.RANDOM`` (or when none is set); under
      ``DETERMINISTIC`` (evaluation) it is exactly ``actor`` and leaves the novelty
      window untouched;
    * it *is* an :class:`AnnealedEGreedyModule`: ``eps`` is a buffer and
      :meth:`step` anneals it, linearly (as ``EGreedyModule``) or multiplicatively
      (the paper: ``eps *= 0.9995`` per step);
    * every visited observation is pushed into the planner's novelty window before
      planning, so after a rollout the window holds the last F visited states;
    * it compiles with ``torch.compile(policy, fullgraph=True)``, as a Collector's
      ``compile_policy`` compiles it (there it decides without data-dependent
      branches; eagerly it draws the random numbers it always drew).

    Optional warm-up (the original code only trusted its model once the prediction
    error fell below a threshold): with ``model_error_threshold`` set, exploring
    steps take uniformly random actions until :meth:`report_model_error` receives an
    error at or below the threshold; from then on the planner decides.

    Keep the policy on the collector's policy device (``policy_device``): a
    :class:`~torchrl.collectors.Collector` that has to move the policy works on a
    copy and syncs buffers from this module, which would overwrite the window the
    copy filled.

    Args:
        actor (TensorDictModuleBase): greedy actor, e.g. :class:`~torchrl.modules.QValueActor`.
        planner (NoveltyPlanner): proposes exploring actions.
        eps_init (float): initial exploration probability. Defaults to 1.0.
        eps_end (float): final exploration probability. Defaults to 0.01 (the paper).
        annealing_num_steps (int): steps for eps to reach ``eps_end``. Defaults to 10_000.

    Keyword Args:
        schedule (str): ``"linear"`` or ``"exponential"``. Defaults to ``"linear"``.
        model_error_threshold (float, optional): enables the random warm-up.
        value_weight (float): an exploring step takes the action of the highest
            ``novelty + value_weight * action_value``: the planner's one-step novelty
            plus the actor's Q-values, which carry novelty further when the Q-network
            learns an intrinsic reward. Defaults to ``0`` (the paper: novelty alone).
        novelty_value (TensorDictModuleBase, optional): ``U``, the discounted novelty
            beyond each action's predicted next state (observation to one value per action,
            learned with :class:`~torchrl_mbe.objectives.NoveltyValueLoss`); an exploring step
            then scores ``max(novelty, U) + value_weight * action_value``
            (:func:`~torchrl_mbe.modules.planner.reachable_novelty`). Defaults to ``None``
            (the paper: the next state's novelty alone).
        action_value (TensorDictModuleBase, optional): the values ``value_weight`` weighs,
            observation to one value per action (the table's
            :class:`~torchrl_mbe.modules.table.TableActionValue`). Defaults to ``None``: the
            actor's ``"action_value"``.
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
        value_weight: float = 0.0,
        novelty_value: TensorDictModuleBase | None = None,
        action_value: TensorDictModuleBase | None = None,
        action_key: NestedKey = "action",
    ) -> None:
        device = planner.candidate_actions.device
        super().__init__(
            planner.action_spec,
            eps_init,
            eps_end,
            annealing_num_steps,
            schedule=schedule,
            action_key=action_key,
            device=device,
        )
        self.actor = actor
        self.planner = planner
        self.model_error_threshold = model_error_threshold
        self.value_weight = float(value_weight)
        self.novelty_value = novelty_value
        self.action_value = action_value
        self.observation_key = planner.in_keys[0]
        self.in_keys = list(dict.fromkeys([*actor.in_keys, self.observation_key]))
        self.out_keys = list(actor.out_keys)
        self.register_buffer("model_trusted", torch.tensor(model_error_threshold is None, device=device))
        self._spec = _complete_output_spec(actor, planner, action_key)

    @property
    def novelty(self):
        """The planner's novelty scorer (its window holds the visited states)."""
        return self.planner.novelty

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
        if torch.compiler.is_compiling() or explore.any():  # compiled: no data-dependent branch
            greedy = tensordict.get(self.action_key)
            exploring = self._exploring_action(tensordict).to(greedy.dtype)
            tensordict.set(self.action_key, torch.where(expand_as_right(explore, greedy), exploring, greedy))
        return tensordict

    def _exploring_action(self, tensordict: TensorDictBase) -> torch.Tensor:
        """The planner's action once the model is trusted, a uniformly random one before.

        Eagerly, only the one needed is drawn, so torch's random stream is what it
        always was. Compiled (``torch.compile(fullgraph=True)``, as a Collector's
        ``compile_policy`` does), both are computed and selected without branching,
        the planner's draws first: from the same random state, a trusted model's
        compiled actions are the eager ones.
        """
        if not torch.compiler.is_compiling():
            return self._planned_action(tensordict) if self.model_trusted else self._random_action(tensordict)
        planned, random = self._planned_action(tensordict), self._random_action(tensordict)
        return torch.where(self.model_trusted, planned, random)

    def _planned_action(self, tensordict: TensorDictBase) -> torch.Tensor:
        observation = tensordict.get(self.observation_key)
        if not self.value_weight and self.novelty_value is None:
            action, _ = self.planner.plan(observation)
            return action
        scores = self.planner.action_scores(observation)
        if self.novelty_value is not None:
            scores = reachable_novelty(scores, action_values(self.novelty_value, observation))
        if self.value_weight:
            values = (
                tensordict.get("action_value")
                if self.action_value is None
                else action_values(self.action_value, observation)
            )
            scores = scores + self.value_weight * values
        return self.planner.actions_at(random_argmax(scores))

    def _random_action(self, tensordict: TensorDictBase) -> torch.Tensor:
        planner = self.planner
        return planner.actions_at(
            torch.randint(planner.num_actions, tensordict.batch_size, device=planner.candidate_actions.device)
        )


def _complete_output_spec(actor: TensorDictModuleBase, planner: NoveltyPlanner, action_key: NestedKey) -> Composite:
    """The policy's output spec with an entry for every output of a Q-value actor.

    A :class:`~torchrl.collectors.Collector` calls a policy once when it is built
    unless the policy's spec names all its output keys; that probe call would
    push a state that was never visited into the novelty window.
    """
    actor_spec = getattr(actor, "spec", None) or Composite()
    shapes = {"action_value": (planner.num_actions,), "chosen_action_value": (1,)}
    spec = Composite({action_key: planner.action_spec})
    for key in actor.out_keys:
        if key == action_key:
            continue
        if actor_spec.get(key, None) is not None:
            spec[key] = actor_spec[key]
        elif key in shapes:
            spec[key] = Unbounded(shapes[key], device=planner.action_spec.device)
    return spec


def check_eps_schedule(eps_init: float, eps_end: float, annealing_num_steps: int, schedule: str) -> None:
    """Raises a one-line ``ValueError`` unless the values make an eps schedule :class:`AnnealedEGreedyModule` can run.

    Examples:
        >>> from torchrl_mbe.modules.exploration import check_eps_schedule
        >>> check_eps_schedule(1.0, 0.01, 9209, "exponential")
        >>> check_eps_schedule(1.0, 0.0, 9209, "exponential")
        Traceback (most recent call last):
        ...
        ValueError: The exponential schedule needs eps_end > 0 (it decays multiplicatively), got eps_end=0.0.
    """
    if not 0.0 <= eps_end <= eps_init <= 1.0:
        raise ValueError(f"Expected 0 <= eps_end <= eps_init <= 1, got eps_init={eps_init}, eps_end={eps_end}.")
    if int(annealing_num_steps) < 1:
        raise ValueError(f"annealing_num_steps must be >= 1, got {annealing_num_steps}.")
    if schedule not in ("linear", "exponential"):
        raise ValueError(f"schedule must be 'linear' or 'exponential', got {schedule!r}.")
    if schedule == "exponential" and eps_end <= 0.0:
        raise ValueError(
            f"The exponential schedule needs eps_end > 0 (it decays multiplicatively), got eps_end={eps_end}."
        )
