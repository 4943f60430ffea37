"""System families (distributions over dynamical systems), batched and seeded, found by name in FAMILIES.

family = make_family(SystemConfig(family="linear"))
traj = family.generate(1000, 50, generator=generator(seed=0))   # Trajectories, y (1000, 51, 5)

Each family is one module that registers itself (mop.systems.base.register_family) and is imported below; a
family outside the package registers the same way when its module is imported (e.g. as a plugin of an
experiment file, or through the entry points of the group mop.families).
"""

from __future__ import annotations

import torch

from mop.systems import (  # noqa: F401 (built-ins)
    cascaded_tanks,
    colored_noise,
    duffing,
    linear,
    linear_inputs,
    lti_mimo,
    lti_siso,
    quadrotor,
    switching,
    upper_triangular,
    wiener_hammerstein,
)
from mop.systems.base import (
    FAMILIES,
    StateSpace,
    SystemConfig,
    SystemFamily,
    SystemParams,
    Trajectories,
    register_family,
    require_params,
    state_space_of,
)


def make_family(config: SystemConfig, dtype: torch.dtype = torch.float32) -> SystemFamily:
    """The family named by config.family; generate() returns tensors of `dtype` (use float64 for filters)."""
    return FAMILIES.get(config.family)(config, dtype)


def generator(seed: int, device: torch.device | str = "cpu") -> torch.Generator:
    """A torch.Generator on `device` seeded with `seed`; the families draw on its device."""
    return torch.Generator(device=device).manual_seed(int(seed))


__all__ = [
    "FAMILIES",
    "StateSpace",
    "SystemConfig",
    "SystemFamily",
    "SystemParams",
    "Trajectories",
    "generator",
    "make_family",
    "register_family",
    "require_params",
    "state_space_of",
]
