"""Transforms of a population's env batch ``[num_envs, M]``: TorchRL's RND with each member's running statistics."""

from __future__ import annotations

import torch
from torchrl.envs.transforms import RNDTransform
from torchrl.envs.transforms.rnd import RunningMeanStd

__all__ = ["PopulationRNDTransform"]


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
        members = obs.shape[-2]
        if self.normalize_obs and self._obs_rms is None:
            self._obs_rms = RunningMeanStd(shape=obs.shape[-2:]).to(obs.device)
        if self.normalize_reward and self._reward_rms is None:
            self._reward_rms = RunningMeanStd(shape=(members, 1)).to(obs.device)
