"""Baselines that need no model: predict zero, or repeat the last output."""

from __future__ import annotations

import torch
from torch import Tensor

from mop.predictors import PREDICTORS, repeat_forecast
from mop.systems.base import Trajectories


@PREDICTORS.register("zero")
class ZeroPredictor:
    """yhat_t = 0 (the prior mean of every output)."""

    name = "zero"

    def predict(self, traj: Trajectories) -> Tensor:
        return torch.zeros_like(traj.y)  # (B, T+1, m)

    def forecast(self, traj: Trajectories, steps: int) -> Tensor:
        """(B, T+1, K, m): 0 for every horizon (NaN beyond T)."""
        return repeat_forecast(self.predict(traj), steps)


@PREDICTORS.register("last")
class LastValuePredictor:
    """yhat_t = y_{t-1}, and yhat_0 = 0. With missing outputs (NaN in y), each channel repeats its last
    measured value (0 before the first)."""

    name = "last"

    def predict(self, traj: Trajectories) -> Tensor:
        y = traj.y if traj.observed is None else carry_forward(traj.y)
        return torch.cat([torch.zeros_like(y[:, :1]), y[:, :-1]], dim=1)  # (B, T+1, m)

    def forecast(self, traj: Trajectories, steps: int) -> Tensor:
        """(B, T+1, K, m): y_{t-1} repeated for every horizon (0 at t = 0; NaN beyond T)."""
        return repeat_forecast(self.predict(traj), steps)


def carry_forward(y: Tensor) -> Tensor:
    """y (B, T+1, m) with each NaN replaced by the channel's last measured value before it (0 before any)."""
    seen = ~torch.isnan(y)
    steps = torch.arange(y.shape[1], device=y.device)[None, :, None].expand_as(y)
    last = torch.where(seen, steps, -1).cummax(dim=1).values  # (B, T+1, m): index of the last measured
    filled = torch.gather(torch.where(seen, y, 0), 1, last.clamp_min(0))
    return torch.where(last >= 0, filled, 0)
