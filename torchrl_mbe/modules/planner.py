"""One-step (or N-step) planning towards the rarest predicted state."""

from __future__ import annotations

import torch
from tensordict import NestedKey, TensorDict, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.data import OneHot, TensorSpec

from torchrl_mbe.modules.actions import discrete_action_spec, num_discrete_actions
from torchrl_mbe.modules.novelty import RollingWindowNovelty

__all__ = ["NoveltyPlanner", "random_argmax", "reachable_novelty"]


def random_argmax(scores: torch.Tensor, dim: int = -1) -> torch.Tensor:
    """Index of the maximum along ``dim``, ties broken uniformly at random.

    An empty novelty window scores every action 0; without random tie-breaking
    the planner would then always pick the first action.
    """
    is_best = scores == scores.amax(dim, keepdim=True)
    return (torch.rand_like(scores, dtype=torch.float32) * is_best).argmax(dim)


def reachable_novelty(next_novelty: torch.Tensor, beyond: torch.Tensor) -> torch.Tensor:
    """The novelty of the rarest state an action reaches: its predicted next state's, or the discounted novelty beyond it.

    ``S(s, a) = max(n(D(s, a)), U(s, a))``, the score of deep model-based exploration
    (:class:`~torchrl_mbe.objectives.NoveltyValueLoss` learns ``U``). A maximum, not a sum:
    a path's value is the rarest state on it, so paths already walked do not add up their
    leftover novelty and outweigh one state never seen.

    Examples:
        >>> import torch
        >>> from torchrl_mbe.modules.planner import reachable_novelty
        >>> reachable_novelty(torch.tensor([0.9, 0.1]), torch.tensor([0.5, 0.7]))
        tensor([0.9000, 0.7000])
    """
    return torch.maximum(next_novelty, beyond)


class NoveltyPlanner(TensorDictModuleBase):
    """Picks the action whose predicted next state is rarest under a novelty scorer.

    For every discrete action ``a`` the dynamics module predicts ``s'_a = D(s, a)``;
    the novelty scorer scores each prediction and the planner writes the argmax of
    the score (the paper's ``argmin_a N(D(s, a) | mu_F, Sigma_F)``), ties broken at
    random, and every action's score under ``scores_key`` (shape ``(*batch, num_actions)``).

    With ``horizon > 1`` (the paper's "future work") the planner rolls the dynamics
    model ``horizon`` steps forward for action *sequences* and scores the final
    predicted state; an action's score is the best score of the sequences that start
    with it. All ``num_actions ** horizon`` sequences are searched while that is at
    most ``max_sequences`` (they are enumerated once, at construction); beyond,
    ``max_sequences`` random sequences are drawn at each call, every first action
    equally often (random shooting).

    Args:
        dynamics (TensorDictModuleBase): reads ``(observation, action)`` (its
            ``in_keys``) and writes one predicted observation.
        novelty (RollingWindowNovelty): scorer with ``score(states)``, higher = rarer.
        action_spec (OneHot, Categorical or Composite): decides how actions are
            encoded; a ``Composite`` (a ``QValueActor``'s ``spec``) is read through
            its ``action_key`` entry, as ``EGreedyModule`` reads it.
        horizon (int): planning depth. Defaults to 1 (the paper).

    Keyword Args:
        max_sequences (int): search budget per call for ``horizon > 1``. Defaults to 1024.
        action_key (NestedKey): where the chosen action is written. Defaults to ``"action"``.
        scores_key (NestedKey): where per-action scores are written.
            Defaults to ``"novelty_scores"``.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl.data import OneHot
        >>> from torchrl_mbe import DynamicsModel, NoveltyPlanner, RollingGaussianDensity
        >>> planner = NoveltyPlanner(DynamicsModel(2, OneHot(3)), RollingGaussianDensity(2, window=50), OneHot(3))
        >>> planner.novelty.update(torch.randn(50, 2))
        >>> td = planner(TensorDict({"observation": torch.zeros(4, 2)}, [4]))
        >>> td["action"].shape, td["novelty_scores"].shape
        (torch.Size([4, 3]), torch.Size([4, 3]))
    """

    def __init__(
        self,
        dynamics: TensorDictModuleBase,
        novelty: RollingWindowNovelty,
        action_spec: TensorSpec,
        horizon: int = 1,
        *,
        max_sequences: int = 1024,
        action_key: NestedKey = "action",
        scores_key: NestedKey = "novelty_scores",
    ) -> None:
        super().__init__()
        if int(horizon) < 1 or int(max_sequences) < 1:
            raise ValueError(f"horizon and max_sequences must be >= 1, got {horizon} and {max_sequences}.")
        self.dynamics = dynamics
        self.novelty = novelty
        self.action_spec = action_spec = discrete_action_spec(action_spec, action_key)
        self.horizon = int(horizon)
        self.num_actions = num_discrete_actions(action_spec)
        self.max_sequences = max(int(max_sequences), self.num_actions)
        self.in_keys = [dynamics.in_keys[0]]
        self.out_keys = [action_key, scores_key]
        if isinstance(action_spec, OneHot):
            candidates = torch.eye(self.num_actions, dtype=action_spec.dtype)
        else:
            candidates = torch.arange(self.num_actions, dtype=action_spec.dtype)
        self.register_buffer("candidate_actions", candidates.to(action_spec.device), persistent=False)
        if self.num_actions**self.horizon <= self.max_sequences:
            actions = torch.arange(self.num_actions, device=action_spec.device)
            sequences = torch.cartesian_prod(*[actions] * self.horizon).reshape(-1, self.horizon).flip(-1)
        else:
            sequences = None  # random shooting: drawn at each call
        self.register_buffer("exhaustive_sequences", sequences, persistent=False)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        action, scores = self.plan(tensordict.get(self.in_keys[0]))
        action_key, scores_key = self.out_keys
        tensordict.set(action_key, action)
        tensordict.set(scores_key, scores)
        return tensordict

    def plan(self, observation: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The action towards the rarest predicted state for each observation, and every action's score.

        What :meth:`forward` writes, on tensors: the action in the spec's
        encoding, shape ``(*batch, *action_shape)``, and the scores, ``(*batch, num_actions)``.

        Examples:
            >>> import torch
            >>> from torchrl.data import OneHot
            >>> from torchrl_mbe import DynamicsModel, NoveltyPlanner, RollingGaussianDensity
            >>> planner = NoveltyPlanner(DynamicsModel(2, OneHot(3)), RollingGaussianDensity(2, window=50), OneHot(3))
            >>> planner.novelty.update(torch.randn(50, 2))
            >>> action, scores = planner.plan(torch.zeros(4, 2))  # one-hot actions, one row of scores per state
            >>> bool((scores[action] == scores.amax(-1)).all())  # each goes to its rarest prediction
            True
        """
        scores = self.action_scores(observation)
        return self.actions_at(random_argmax(scores)), scores

    def actions_at(self, index: torch.Tensor) -> torch.Tensor:
        """The actions of integer ``index`` (any shape), in the spec's encoding, shape ``(*index.shape, *action_shape)``.

        Examples:
            >>> import torch
            >>> from torchrl.data import OneHot
            >>> from torchrl_mbe import DynamicsModel, NoveltyPlanner, RollingGaussianDensity
            >>> planner = NoveltyPlanner(DynamicsModel(2, OneHot(3)), RollingGaussianDensity(2), OneHot(3))
            >>> planner.actions_at(torch.tensor(2))
            tensor([False, False,  True])
        """
        # flat, then reshaped: indexing with a 0-d tensor would read it as a Python int, which torch.compile cannot trace
        candidates = self.candidate_actions
        return candidates[index.reshape(-1)].reshape(*index.shape, *candidates.shape[1:])

    @torch.no_grad()
    def action_scores(self, observation: torch.Tensor) -> torch.Tensor:
        """Novelty score of each first action, shape ``(*batch, num_actions)``."""
        return self._best_per_first_action(self.novelty.score(self._rollout(observation, self._action_sequences())))

    @torch.no_grad()
    def replayed_action_scores(self, observation: torch.Tensor) -> torch.Tensor:
        """Novelty score of each first action from observations of no one env (a replay buffer's), ``(B, *members, num_actions)``.

        ``observation`` is ``(B, F)``, or ``(B, M, F)`` for a scorer of ``batch_shape``
        ``(E, M)``. Each prediction is scored against every env's window and the scores
        are averaged over the ``E`` envs.

        Examples:
            >>> import torch
            >>> from torchrl.data import OneHot
            >>> from torchrl_mbe import DynamicsModel, NoveltyPlanner, VisitCounts
            >>> planner = NoveltyPlanner(DynamicsModel(2, OneHot(3)), VisitCounts(2, batch_shape=[4]), OneHot(3))
            >>> planner.replayed_action_scores(torch.zeros(8, 2)).shape  # 8 replayed states, 4 envs' counts
            torch.Size([8, 3])
        """
        final_states = self._rollout(observation, self._action_sequences())  # (sequences, B, *members, F)
        batch_shape = self.novelty.batch_shape
        if not batch_shape:
            return self._best_per_first_action(self.novelty.score(final_states))
        each_env = final_states.unsqueeze(2).expand(*final_states.shape[:2], batch_shape[0], *final_states.shape[2:])
        return self._best_per_first_action(self.novelty.score(each_env).mean(2))

    def _best_per_first_action(self, sequence_scores: torch.Tensor) -> torch.Tensor:
        """Each first action's best sequence score, ``(*batch, num_actions)``, from ``(num_sequences, *batch)``."""
        return sequence_scores.unflatten(0, (-1, self.num_actions)).amax(0).movedim(0, -1)

    def _action_sequences(self) -> torch.Tensor:
        """Action indices, shape ``(num_sequences, horizon)``; sequence ``i`` starts with action ``i % num_actions``."""
        if self.exhaustive_sequences is not None:
            return self.exhaustive_sequences
        num_actions, device = self.num_actions, self.candidate_actions.device
        num_sequences = self.max_sequences - self.max_sequences % num_actions
        first = torch.arange(num_sequences, device=device) % num_actions
        rest = torch.randint(num_actions, (num_sequences, self.horizon - 1), device=device)
        return torch.cat([first.unsqueeze(-1), rest], -1)

    def _rollout(self, observation: torch.Tensor, sequences: torch.Tensor) -> torch.Tensor:
        """Predicted states after each sequence, shape ``(num_sequences, *batch, obs_dim)``."""
        observation_key, action_key = self.dynamics.in_keys
        batch_shape = observation.shape[:-1]
        state = observation.expand(sequences.shape[0], *observation.shape)
        for step in range(self.horizon):
            action = self.candidate_actions[sequences[:, step]]
            action = action.view(action.shape[0], *[1] * len(batch_shape), *action.shape[1:])
            action = action.expand(sequences.shape[0], *batch_shape, *action.shape[len(batch_shape) + 1 :])
            inputs = TensorDict({observation_key: state, action_key: action}, batch_size=state.shape[:-1])
            state = self.dynamics(inputs).get(self.dynamics.out_keys[0])
        return state
