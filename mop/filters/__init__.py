"""Classical predictors, batched over systems: Kalman (and steady-state), RLS, subspace identification,
simple baselines; the quadrotor EKF / UKF / particle filter live in ekf.py, ukf.py, particle.py."""

from mop.filters.colored import ColoredNoiseKalmanPredictor, colored_kalman_filter
from mop.filters.kalman import (
    KalmanPredictor,
    KalmanResult,
    innovation_floor,
    kalman_filter,
    kalman_predict,
    optimal_mse_curve,
    solve_filter_dare,
    steady_state_gain,
)
from mop.filters.rls import AdaptiveOrderRLSPredictor, RLSPredictor, adaptive_order_rls_predict, rls_predict
from mop.filters.simple import LastValuePredictor, ZeroPredictor
from mop.filters.subspace import N4SIDKalmanPredictor, identify, n4sid_kalman_predict

__all__ = [
    "KalmanPredictor",
    "KalmanResult",
    "kalman_filter",
    "kalman_predict",
    "solve_filter_dare",
    "steady_state_gain",
    "innovation_floor",
    "optimal_mse_curve",
    "ColoredNoiseKalmanPredictor",
    "colored_kalman_filter",
    "RLSPredictor",
    "AdaptiveOrderRLSPredictor",
    "rls_predict",
    "adaptive_order_rls_predict",
    "ZeroPredictor",
    "LastValuePredictor",
    "N4SIDKalmanPredictor",
    "identify",
    "n4sid_kalman_predict",
]
