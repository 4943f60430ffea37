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
    """yhat_t = y_{t-1}, and yhat_0 = 0."""

    name = "last"

    def predict(self, traj: Trajectories) -> Tensor:
        return torch.cat([torch.zeros_like(traj.y[:, :1]), traj.y[:, :-1]], dim=1)  # (B, T+1, m)

    def forecast(self, traj: Trajectories, steps: int) -> Tensor:
        """(B, T+1, K, m): y_{t-1} repeated for every horizon (0 at t = 0; NaN beyond T)."""
        return repeat_forecast(self.predict(traj), steps)
