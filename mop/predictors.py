"""The one interface every predictor answers, classical or learned.

A predictor maps a batch of trajectories to one-step predictions:
    yhat = predictor.predict(traj)          # (B, T+1, m)
where yhat[:, t] predicts y[:, t] using only y[:, :t] and u[:, :t] (plus the system's parameters in
traj.params for predictors that know the system, e.g. the Kalman filter). yhat[:, 0] uses no data.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from torch import Tensor

from mop.systems.base import Trajectories


@runtime_checkable
class Predictor(Protocol):
    name: str

    def predict(self, traj: Trajectories) -> Tensor:
        """(B, T+1, m) one-step predictions, yhat[:, t] from y[:, :t] (and u[:, :t])."""
        ...
