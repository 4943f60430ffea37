"""System families (distributions over dynamical systems), batched and seeded.

family = make_family(SystemConfig(family="linear"))
traj = family.generate(1000, 50, generator=generator(seed=0))   # Trajectories, y (1000, 51, 5)
"""

from __future__ import annotations

import torch

from mop.config import SystemConfig
from mop.systems.base import SystemFamily, Trajectories
from mop.systems.linear import LinearFamily
from mop.systems.quadrotor import QuadrotorFamily
from mop.systems.switching import SwitchingFamily


def make_family(config: SystemConfig, dtype: torch.dtype = torch.float32) -> SystemFamily:
    """The family named by config.family; generate() returns tensors of `dtype` (use float64 for filters)."""
    if config.family == "quadrotor":
        return QuadrotorFamily(config, dtype)
    if config.family == "switching":
        return SwitchingFamily(config, dtype)
    return LinearFamily(config, dtype)


def generator(seed: int, device: torch.device | str = "cpu") -> torch.Generator:
    """A torch.Generator on `device` seeded with `seed`; the families draw on its device."""
    return torch.Generator(device=device).manual_seed(int(seed))


__all__ = [
    "make_family",
    "generator",
    "SystemFamily",
    "Trajectories",
    "LinearFamily",
    "SwitchingFamily",
    "QuadrotorFamily",
]
