"""Trajectories: a batch of simulated or measured outputs (and inputs, states, system parameters).

Time indexing used everywhere in mop: a trajectory of horizon T holds outputs y_0..y_T (T + 1 of them);
inputs u_t (where a family has them) act between y_t and y_{t+1}.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from mop.errors import MopError
from mop.systems.params import SystemParams


@dataclass
class Trajectories:
    """A batch of simulated (or measured) trajectories.

    y: (B, T+1, m) outputs y_0..y_T; NaN marks an output channel not measured at a step (a gap; `observed`
        is the mask). Every predictor skips what was not measured; inputs u must be complete.
    u: (B, T+1, k) inputs u_0..u_T, or None for families without inputs.
    x: (B, T+1, n) true states, or None for measured data.
    params: the systems' parameters, the family's typed SystemParams (each field with leading dim B, e.g.
        params.A (B, n, n)), or None (measured data); what a predictor that knows the system reads.
    family: name of the family that made it ("" for user data); its state_space(params) describes the systems.
    """

    y: Tensor
    u: Tensor | None = None
    x: Tensor | None = None
    params: SystemParams | None = None
    family: str = ""

    def __post_init__(self) -> None:
        y_shape = tuple(getattr(self.y, "shape", ()))
        if len(y_shape) != 3:
            raise MopError(
                f"Trajectories.y has shape {y_shape}; it is a batch (B, T+1, m): add the batch axis "
                "(y[None]), or give one record to mop.estimators as it is"
            )
        u_shape = None if self.u is None else tuple(self.u.shape)
        if u_shape is not None and (len(u_shape) != 3 or u_shape[:2] != y_shape[:2]):
            raise MopError(
                f"Trajectories.u has shape {u_shape} and y {y_shape}; u is (B, T+1, k) of the "
                "same B and T+1 as y"
            )
        if self.params is not None and not isinstance(self.params, SystemParams):
            raise MopError(
                f"Trajectories.params must be the family's parameter type (a SystemParams), got "
                f"{type(self.params).__name__}; a family declares it as `Params` (docs/design/extending.md)"
            )

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

    @property
    def observed(self) -> Tensor | None:
        """(B, T+1, m) bool, True where y was measured; None when every entry was (no gaps)."""
        seen = ~torch.isnan(self.y)
        return None if bool(seen.all()) else seen

    @property
    def num_missing(self) -> int:
        """How many scalar outputs are missing (NaN in y)."""
        return int(torch.isnan(self.y).sum())

    def model_inputs(self) -> Tensor:
        """(B, T+1, m + k): [y_t, u_t] per step, the sequence a learned predictor reads (NaN where y is
        missing; mop.missing.masked_inputs gives the layout of a model with an observation mask)."""
        return self.y if self.u is None else torch.cat([self.y, self.u], dim=-1)

    def _map(self, fn: Callable[[Tensor], Tensor]) -> Trajectories:
        opt = lambda t: None if t is None else fn(t)  # noqa: E731
        params = None if self.params is None else self.params.map(fn)
        return Trajectories(fn(self.y), opt(self.u), opt(self.x), params, self.family)

    def to(self, device: torch.device | str) -> Trajectories:
        return self._map(lambda t: t.to(device))

    def select(self, index: slice | Tensor) -> Trajectories:
        """The subset of systems picked by `index` along the batch dimension."""
        return self._map(lambda t: t[index])

    def to_numpy_dict(self) -> dict[str, np.ndarray]:
        """Flat dict for np.savez: y, u (if any), x (if any), params as param_<name>, and family."""
        out = {"y": self.y.cpu().numpy()}
        if self.u is not None:
            out["u"] = self.u.cpu().numpy()
        if self.x is not None:
            out["x"] = self.x.cpu().numpy()
        if self.params is not None:
            out.update({f"param_{k}": v for k, v in self.params.to_arrays().items()})
        if self.family:
            out["family"] = np.array(self.family)
        return out
