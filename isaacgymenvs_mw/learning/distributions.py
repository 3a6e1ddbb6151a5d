"""Action distributions for rsl_rl that sample without a host-device sync."""

from __future__ import annotations

import torch
from rsl_rl.modules.distribution import GaussianDistribution as _RslRlGaussian


class GaussianDistribution(_RslRlGaussian):
    """rsl_rl's diagonal Gaussian, sampled as mean + std * N(0, 1).

    ``torch.normal(mean, std)`` checks ``std >= 0`` on the host, which stalls the rollout once per step on CUDA;
    std is clamped positive already, so the check buys nothing. Same parameters, so checkpoints are interchangeable.
    """

    def sample(self) -> torch.Tensor:
        mean, std = self._distribution.mean, self._distribution.stddev  # type: ignore[union-attr]
        return mean + std * torch.randn_like(mean)
