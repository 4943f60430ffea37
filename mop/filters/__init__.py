"""Classical predictors, batched over systems, each registered in mop.predictors.PREDICTORS by its module:
the Gaussian filtering core (gaussian.py) with the Kalman filter, EKF and UKF; the particle filter; the exact
colored-noise filter; the switching baseline kalman-system1 (system1.py); RLS; subspace identification;
simple baselines."""

from mop.filters import (  # noqa: F401 (each module registers its predictors)
    arx,
    bayes,
    colored,
    ekf,
    gaussian,
    kalman,
    particle,
    rls,
    simple,
    subspace,
    system1,
    ukf,
)
from mop.filters.kalman import (
    KalmanPredictor,
    KalmanResult,
    kalman_filter,
    kalman_predict,
    solve_filter_dare,
    steady_state_gain,
)
from mop.filters.rls import AdaptiveOrderRLSPredictor, RLSPredictor, adaptive_order_rls_predict, rls_predict
from mop.filters.simple import LastValuePredictor, ZeroPredictor
from mop.filters.subspace import N4SIDKalmanPredictor, identify, identify_with_inputs, n4sid_kalman_predict

__all__ = [
    "KalmanPredictor",
    "KalmanResult",
    "kalman_filter",
    "kalman_predict",
    "solve_filter_dare",
    "steady_state_gain",
    "RLSPredictor",
    "AdaptiveOrderRLSPredictor",
    "rls_predict",
    "adaptive_order_rls_predict",
    "ZeroPredictor",
    "LastValuePredictor",
    "N4SIDKalmanPredictor",
    "identify",
    "identify_with_inputs",
    "n4sid_kalman_predict",
]
