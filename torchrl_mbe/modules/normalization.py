"""Feature standardization whose statistics are module buffers."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

__all__ = ["Standardize"]


class Standardize(nn.Module):
    """``(x - loc) / scale`` per feature; identity until :meth:`fit`.

    The statistics are buffers, so they are saved in ``state_dict`` beside the
    weights they feed and follow ``.to(device)``.

    Args:
        num_features (int or sequence of int): size of the last dimension, or the
            statistics' whole shape: a population's ``(M, F)`` keeps one set per
            member, for inputs ``[*B, M, F]``.

    Keyword Args:
        device (torch.device, optional): where the buffers live.

    Examples:
        >>> import torch
        >>> from torchrl_mbe.modules import Standardize
        >>> standardize = Standardize(2)
        >>> standardize.fit(torch.tensor([[0.0, 10.0], [2.0, 30.0]]))
        >>> standardize(torch.tensor([1.0, 20.0]))
        tensor([0., 0.])
        >>> standardize.fit(torch.tensor([[0.0, 10.0], [0.0, 30.0]]))  # the first feature never varied
        >>> standardize(torch.tensor([1.0, 20.0]))
        tensor([1., 0.])
        >>> members = Standardize((2, 1))  # two members, one feature each
        >>> members.fit(torch.tensor([[[0.0], [0.0]], [[2.0], [20.0]]]))  # [samples, members, features]
        >>> members.scale.flatten().tolist()
        [1.4142135381698608, 14.142135620117188]
    """

    def __init__(self, num_features: int | Sequence[int], *, device: torch.device | str | None = None) -> None:
        super().__init__()
        shape = (num_features,) if isinstance(num_features, int) else tuple(num_features)
        self.register_buffer("loc", torch.zeros(shape, device=device))
        self.register_buffer("scale", torch.ones(shape, device=device))

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        return (features - self.loc) / self.scale

    @torch.no_grad()
    def fit(self, samples: torch.Tensor, min_scale: float = 1e-6) -> None:
        """Sets ``loc``/``scale`` to the mean and standard deviation of ``samples`` (``(N, *shape)``).

        A feature whose standard deviation is at most ``min_scale`` (one that did
        not vary in ``samples``, like LunarLander's leg contacts before the first
        touch) keeps scale 1, as in scikit-learn's ``StandardScaler``: dividing by
        a floor would turn its first change into a value of millions.
        """
        # integer samples too (a one-hot Discrete observation)
        samples = samples.reshape(-1, *self.loc.shape).to(self.loc.dtype)
        if samples.shape[0] < 2:
            raise ValueError("Standardize.fit needs at least two samples.")
        std = samples.std(0)
        self.loc.copy_(samples.mean(0))
        self.scale.copy_(torch.where(std > min_scale, std, torch.ones_like(std)))
