"""Shared containers and the interface every system family implements.

Time indexing used everywhere in mop: a trajectory of horizon T holds outputs y_0..y_T
(T + 1 of them). Inputs u_t (where a family has them) act between y_t and y_{t+1}:
x_{t+1} = f(x_t, u_t) + w_t, y_t = g(x_t) + v_t.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
import torch
from torch import Tensor


@dataclass
class Trajectories:
    """A batch of simulated (or measured) trajectories.

    y: (B, T+1, m) outputs y_0..y_T.
    u: (B, T+1, k) inputs u_0..u_T, or None for families without inputs.
    x: (B, T+1, n) true states, or None for measured data.
    params: per-system parameters, each with leading dim B (e.g. "A": (B, n, n), "C": (B, m, n),
        "Q": (B, n, n), "R": (B, m, m)); what a predictor that knows the system may use.
    family: name of the family that made it ("" for user data).
    """

    y: Tensor
    u: Tensor | None = None
    x: Tensor | None = None
    params: dict[str, Tensor] = field(default_factory=dict)
    family: str = ""

    @property
    def num_systems(self) -> int:
        return self.y.shape[0]

    @property
    def horizon(self) -> int:
        """T: the number of steps; there are T + 1 outputs."""
        return self.y.shape[1] - 1

    @property
    def output_dim(self) -> int:
        return self.y.shape[2]

    @property
    def input_dim(self) -> int:
        return 0 if self.u is None else self.u.shape[2]

    def model_inputs(self) -> Tensor:
        """(B, T+1, m + k): [y_t, u_t] per step, the sequence a learned predictor reads."""
        return self.y if self.u is None else torch.cat([self.y, self.u], dim=-1)

    def to(self, device: torch.device | str) -> Trajectories:
        move = lambda t: None if t is None else t.to(device)  # noqa: E731
        return Trajectories(
            move(self.y),
            move(self.u),
            move(self.x),
            {k: v.to(device) for k, v in self.params.items()},
            self.family,
        )

    def select(self, index: slice | Tensor) -> Trajectories:
        """The subset of systems picked by `index` along the batch dimension."""
        pick = lambda t: None if t is None else t[index]  # noqa: E731
        return Trajectories(
            pick(self.y),
            pick(self.u),
            pick(self.x),
            {k: v[index] for k, v in self.params.items()},
            self.family,
        )

    def to_numpy_dict(self) -> dict[str, np.ndarray]:
        """Flat dict for np.savez: y, u (if any), x (if any), and params as param_<name>."""
        out = {"y": self.y.cpu().numpy()}
        if self.u is not None:
            out["u"] = self.u.cpu().numpy()
        if self.x is not None:
            out["x"] = self.x.cpu().numpy()
        out.update({f"param_{k}": v.cpu().numpy() for k, v in self.params.items()})
        return out


class SystemFamily(Protocol):
    """A distribution over dynamical systems (D_sys in the paper).

    Implementations are batched: one call samples or simulates B systems at once, on any device,
    and all randomness comes from the `torch.Generator` passed in (same seed -> same numbers).
    """

    name: str
    state_dim: int
    output_dim: int
    input_dim: int  # 0 when the family has no inputs

    def sample(self, num_systems: int, *, generator: torch.Generator) -> dict[str, Tensor]:
        """Parameters of `num_systems` systems, each tensor with leading dim B."""
        ...

    def simulate(
        self, params: dict[str, Tensor], horizon: int, *, generator: torch.Generator
    ) -> Trajectories:
        """One trajectory of `horizon` steps (horizon + 1 outputs) per system."""
        ...

    def generate(self, num_systems: int, horizon: int, *, generator: torch.Generator) -> Trajectories:
        """sample + simulate, redrawing systems whose trajectory leaves the bound.

        DESIGN.md: every |x|, |y| <= 50.
        """
        ...
