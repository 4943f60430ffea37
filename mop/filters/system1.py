"""The authors' switching baseline (Fig. 2c): the Kalman filter of system 1, kept after the switch.

On switching trajectories (mop.systems.switching) params.A, params.C are system 1's; this filter never learns
of system 2, so after switch_time it predicts with the wrong model, as the authors' code does.
"""

from __future__ import annotations

from torch import Tensor

from mop.filters.gaussian import filter_distribution, filter_forecast, kalman_step
from mop.predictors import PREDICTORS
from mop.systems.base import StateSpace, Trajectories, linear_state_space, require_params

NEEDS = ("A", "C", "Q", "R", "P0")  # the fields of system 1's linear model (LinearParams has them)


@PREDICTORS.register("kalman-system1", needs_system=True, gaussian=True)
class KalmanKeepingSystem1:
    """The Kalman filter of the linear model in params A, C, Q, R, P0 (system 1 of a switch)."""

    name = "kalman-system1"

    @staticmethod
    def _model(traj: Trajectories) -> StateSpace:
        require_params(traj.params, NEEDS, by="kalman-system1")
        p = traj.params
        return linear_state_space(p.A, p.C, p.Q, p.R, p.P0)

    def predict_distribution(self, traj: Trajectories) -> tuple[Tensor, Tensor]:
        """Each (B, T+1, m): system 1's predictive mean and variance of y_t."""
        return filter_distribution(self._model(traj), kalman_step, traj)

    def forecast(self, traj: Trajectories, steps: int) -> Tensor:
        """(B, T+1, K, m): system 1's Kalman forecast (mop.filters.gaussian.filter_forecast)."""
        return filter_forecast(self._model(traj), kalman_step, traj, steps)[0]

    def predict(self, traj: Trajectories) -> Tensor:
        return self.predict_distribution(traj)[0]
