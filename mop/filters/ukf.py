"""Unscented Kalman filter one-step predictions, batched over systems: mop.filters.gaussian's core with the
unscented time update (2n + 1 sigma points, Julier / Merwe scaling; see gaussian.sigma_points).

The output map is linear (y = C x + v), for which the unscented measurement update is exactly the Kalman
update, so the core's condition_on serves. With a state projection (the quadrotor's clipping) "ukf" clips
its predicted mean only (0.50 over t in [20, 50) on the quadrotor; clipping the posterior too, as the EKF
does, scores 0.65); "ukf-noclip" does not clip. On a linear system the UKF equals the Kalman filter.
"""

from __future__ import annotations

from mop.filters.gaussian import GaussianFilterPredictor, ukf_step_with
from mop.predictors import PREDICTORS


@PREDICTORS.register("ukf", needs_system=True, gaussian=True)
class UKFPredictor(GaussianFilterPredictor):
    """The UKF that knows each system (alpha, beta, kappa: sigma-point scaling)."""

    name = "ukf"

    def __init__(
        self, alpha: float = 1.0, beta: float = 0.0, kappa: float = 0.0, project: bool = True
    ) -> None:
        super().__init__(ukf_step_with(alpha, beta, kappa), project, "ukf" if project else "ukf-noclip")


PREDICTORS.add("ukf-noclip", lambda: UKFPredictor(project=False), needs_system=True, gaussian=True)
