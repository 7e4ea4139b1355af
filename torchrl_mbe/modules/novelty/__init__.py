"""Novelty scorers over a rolling window of recently visited states.

Every scorer honours one contract: ``update(states)`` pushes visited states into
the window and ``score(states)`` returns one number per state, higher = rarer.

Shapes follow :mod:`torch.distributions`: a scorer built with
``batch_shape=(B,)`` keeps one window per batch element (one per environment of
a batched env) and accepts states of shape ``(*sample_shape, B, num_features)``.
With the default ``batch_shape=()`` one window is shared and any leading
dimensions are sample dimensions.

Every scorer here also runs under ``torch.compile(fullgraph=True)`` (a
Collector's ``compile_policy``): compiled, it scores against the whole window
with its empty slots masked out, since no shape may depend on how many states
are stored; eagerly it reads exactly the stored states.
"""

from torchrl_mbe.modules.novelty.counts import VisitCounts
from torchrl_mbe.modules.novelty.gaussian import DiagonalGaussianDensity, RollingGaussianDensity
from torchrl_mbe.modules.novelty.kernel import GaussianKernelNovelty, KernelDensityNovelty, KNearestNovelty
from torchrl_mbe.modules.novelty.window import RollingWindowNovelty

__all__ = [
    "DiagonalGaussianDensity",
    "GaussianKernelNovelty",
    "KNearestNovelty",
    "KernelDensityNovelty",
    "RollingGaussianDensity",
    "RollingWindowNovelty",
    "VisitCounts",
]
