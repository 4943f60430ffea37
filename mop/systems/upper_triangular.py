"""Upper-triangular linear systems (the paper's Fig. 4): A has diagonal U[-rho, rho] (its eigenvalues) and
strictly upper part U[-1, 1], so ||A^k|| can grow far beyond rho(A)^k before it decays (transient growth)."""

from __future__ import annotations

import torch
from torch import Tensor

from mop.systems.base import register_family, uniform
from mop.systems.linear import LinearConfig, LinearFamily, check_stable


def sample_upper_triangular_A(
    num_systems: int, state_dim: int, spectral_radius: float, generator: torch.Generator
) -> Tensor:
    """(B, n, n) diagonal U[-rho, rho] (the eigenvalues), strictly upper part U[-1, 1], zeros below."""
    check_stable(spectral_radius)
    A = uniform((num_systems, state_dim, state_dim), -1.0, 1.0, generator).triu(1)
    diag = uniform((num_systems, state_dim), -spectral_radius, spectral_radius, generator)
    return A + torch.diag_embed(diag)


@register_family("upper-triangular", LinearConfig)
class UpperTriangularFamily(LinearFamily):
    """As LinearFamily with upper-triangular A; same knobs (LinearConfig)."""

    def sample_A(self, num_systems: int, generator: torch.Generator) -> Tensor:
        return sample_upper_triangular_A(num_systems, self.state_dim, self.config.spectral_radius, generator)
