"""Transforms: TorchRL's RND with each member's running statistics on a population's env batch ``[num_envs, M]``,
a novelty scorer's intrinsic reward, and what Bootstrapped DQN needs from the env (the acting head of each
episode, a bootstrap mask per step)."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torchrl.data import Binary, Categorical, Composite, Unbounded
from torchrl.envs.transforms import RNDTransform, Transform
from torchrl.envs.transforms.rnd import RunningMeanStd

__all__ = ["BootstrapHeads", "NoveltyReward", "PopulationRNDTransform"]


class BootstrapHeads(Transform):
    """What Bootstrapped DQN needs from the env: the head that acts in each episode, and a bootstrap mask per step.

    At a reset, every env that resets draws its head uniformly among ``num_heads``
    (torch's generator) into ``head_key``; every step carries it on, so one head acts
    for a whole episode (Osband et al.'s Thompson sampling over the ensemble). Every
    step also writes ``mask_key``: ``num_heads`` Bernoulli(``mask_prob``) draws, whether
    each head trains on that transition (stored with it in the replay buffer).

    Args:
        num_heads (int): the ensemble's size ``K``.
        mask_prob (float): each head's chance of training on a transition. Defaults to
            ``1.0`` (bsuite's ``boot_dqn``: the heads differ by their initialization and priors).

    Keyword Args:
        head_key (NestedKey): where the head index goes. Defaults to ``"head"``.
        mask_key (NestedKey): where the mask goes. Defaults to ``"bootstrap_mask"``.

    Examples:
        >>> from torchrl_mbe import make_env
        >>> from torchrl_mbe.envs.transforms import BootstrapHeads
        >>> env = make_env("mountaincar", num_envs=4, seed=0)
        >>> _ = env.append_transform(BootstrapHeads(num_heads=10, mask_prob=0.5))
        >>> rollout = env.rollout(3)
        >>> rollout["head"].shape, bool((rollout["head"] == rollout["head"][:, :1]).all())  # one head per episode
        (torch.Size([4, 3]), True)
        >>> rollout["next", "bootstrap_mask"].shape
        torch.Size([4, 3, 10])
    """

    def __init__(
        self, num_heads: int, mask_prob: float = 1.0, *, head_key: str = "head", mask_key: str = "bootstrap_mask"
    ) -> None:
        if num_heads < 1 or not 0.0 <= mask_prob <= 1.0:
            raise ValueError(f"num_heads must be positive and mask_prob in [0, 1], got {num_heads} and {mask_prob}.")
        super().__init__(in_keys=[], out_keys=[head_key, mask_key])
        self.num_heads, self.mask_prob, self.head_key, self.mask_key = num_heads, mask_prob, head_key, mask_key

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        batch_size, device = tensordict_reset.batch_size, tensordict_reset.device
        heads = torch.randint(self.num_heads, batch_size, device=device)
        previous = tensordict.get(self.head_key, None) if tensordict is not None else None
        reset = tensordict.get(self.parent.reset_keys[0], None) if tensordict is not None else None
        if previous is not None and reset is not None:
            heads = torch.where(reset.reshape(batch_size), heads, previous)
        tensordict_reset.set(self.head_key, heads)
        tensordict_reset.set(self.mask_key, self._mask(batch_size, device))
        return tensordict_reset

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        next_tensordict.set(self.head_key, tensordict.get(self.head_key))
        next_tensordict.set(self.mask_key, self._mask(next_tensordict.batch_size, next_tensordict.device))
        return next_tensordict

    def _mask(self, batch_size: torch.Size, device: torch.device) -> torch.Tensor:
        if self.mask_prob == 1.0:  # no draw: the random stream stays that of a run without masks
            return torch.ones(*batch_size, self.num_heads, dtype=torch.bool, device=device)
        return torch.rand(*batch_size, self.num_heads, device=device) < self.mask_prob

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        batch_size, device = observation_spec.shape, observation_spec.device
        observation_spec[self.head_key] = Categorical(self.num_heads, shape=batch_size, device=device)
        observation_spec[self.mask_key] = Binary(self.num_heads, shape=(*batch_size, self.num_heads), device=device)
        return observation_spec


class PopulationRNDTransform(RNDTransform):
    """TorchRL's ``RNDTransform`` on a population's env batch ``[*B, M]``: each member's own running statistics.

    ``RNDTransform`` pools every observation of the batch into one running mean and
    variance (``shape=(F,)``) and one intrinsic-reward variance (``shape=()``); here
    they are ``(M, F)`` and ``(M, 1)``, TorchRL's ``RunningMeanStd`` over the batch
    dimensions before the member dimension, so a member's normalized observations
    and rewards depend on its own frames only. The target and predictor networks
    map ``[*B, M, F]`` to ``[*B, M, E]`` (:func:`make_members_mlp`'s); everything
    else is ``RNDTransform``'s. Pass :attr:`obs_rms` to :class:`PopulationRNDLoss`.

    Examples:
        >>> from torchrl_mbe import make_env
        >>> from torchrl_mbe.envs.transforms import PopulationRNDTransform
        >>> from torchrl_mbe.modules.networks import make_members_mlp
        >>> env = make_env("mountaincar", num_envs=(4, 3), seed=0)  # 4 envs for each of 3 members
        >>> rnd = PopulationRNDTransform(*(make_members_mlp(2, 8, [16], num_members=3, glorot=False) for _ in range(2)))
        >>> _ = env.append_transform(rnd)
        >>> env.rollout(5)["next", "intrinsic_reward"].shape, rnd.obs_rms.mean.shape, rnd.reward_rms.var.shape
        (torch.Size([4, 3, 5, 1]), torch.Size([3, 2]), torch.Size([3, 1]))
    """

    def _maybe_init_rms(self, obs: torch.Tensor) -> None:
        # Private hook: RNDTransform fixes its statistics' shape to the features and offers no public
        # option for one set per group of the batch (no upstream issue filed yet).
        num_members = obs.shape[-2]
        if self.normalize_obs and self._obs_rms is None:
            self._obs_rms = RunningMeanStd(shape=obs.shape[-2:]).to(obs.device)
        if self.normalize_reward and self._reward_rms is None:
            self._reward_rms = RunningMeanStd(shape=(num_members, 1)).to(obs.device)


class NoveltyReward(Transform):
    """A novelty scorer's intrinsic reward: each step's next observation, scored against the states visited before it.

    The scorer is the one the exploration policy fills (a
    :class:`~torchrl_mbe.ModelBasedExplorationPolicy` pushes every visited
    observation into its planner's window before acting), so the next observation
    of a step is scored against the window as it stood when the step was taken:
    a state the window has not seen scores high. The transform only reads the
    scorer; the policy alone writes its window. Written under
    ``("next", out_key)`` beside the reward, as TorchRL's ``RNDTransform`` writes its own.

    Args:
        novelty (RollingWindowNovelty): any scorer of :mod:`torchrl_mbe.modules.novelty`
            (``score(states)``, higher = rarer), with one window per env of the batch.

    Keyword Args:
        in_key (NestedKey): the observation scored. Defaults to ``"observation"``.
        out_key (NestedKey): the reward written. Defaults to ``"intrinsic_reward"``.

    Examples:
        >>> import torch
        >>> from torchrl_mbe import VisitCounts, make_env
        >>> from torchrl_mbe.envs.transforms import NoveltyReward
        >>> env = make_env("deepsea", size=4)  # one env: a batch of [1]
        >>> counts = VisitCounts(16, batch_shape=env.batch_size)
        >>> _ = env.append_transform(NoveltyReward(counts))
        >>> left = lambda td: td.set("action", torch.tensor([[1, 0]]))  # the same moves every episode
        >>> first = env.rollout(3, left)
        >>> first["next", "intrinsic_reward"].flatten()  # nothing visited yet: every state is new
        tensor([1., 1., 1.])
        >>> counts.update(first["next", "observation"].transpose(0, 1))  # what the policy's window holds after it
        >>> env.rollout(3, left)["next", "intrinsic_reward"].flatten()  # the same states again, each visited once
        tensor([0.7071, 0.7071, 0.7071])
    """

    def __init__(self, novelty: torch.nn.Module, *, in_key="observation", out_key="intrinsic_reward") -> None:
        super().__init__(in_keys=[in_key], out_keys=[out_key])
        self.novelty = novelty

    @torch.no_grad()
    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        observation = next_tensordict.get(self.in_keys[0])
        next_tensordict.set(self.out_keys[0], self.novelty.score(observation.float()).unsqueeze(-1))
        return next_tensordict

    def transform_reward_spec(self, reward_spec: Composite) -> Composite:
        reward_spec[self.out_keys[0]] = Unbounded(
            (*reward_spec.shape, 1), device=reward_spec.device, dtype=torch.float32
        )
        return reward_spec
