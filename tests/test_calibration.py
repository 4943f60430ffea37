"""Calibration of the Kalman filter's own predictive distribution: a statistical test with a stated tolerance.

For the true KF, the innovation y_t - C m_t of output i is exactly N(0, S_t,ii) and innovations are
independent across time and systems, so "inside the central 90% interval" for output 0 over N systems and T
steps is Binomial(N T, 0.9). The empirical coverage must fall in the 99.9% binomial interval around 0.90.
"""

import torch
from scipy.stats import binom

from mop.config import SystemConfig
from mop.metrics import coverage
from mop.predictors import make_predictor
from mop.systems import generator, make_family


def test_kalman_90_percent_interval_is_calibrated():
    traj = make_family(SystemConfig(family="linear"), dtype=torch.float64).generate(
        400, 50, generator=generator(11)
    )
    mean, var = make_predictor("kalman").predict_distribution(traj)
    y, mean, var = traj.y[:, 1:, :1], mean[:, 1:, :1], var[:, 1:, :1]  # output 0, t >= 1
    n = y.numel()
    low, high = binom.ppf([0.0005, 0.9995], n, 0.9) / n
    observed = coverage(y, mean, var, 0.9)
    assert low <= observed <= high, (observed, low, high)
    # a filter that is 30% overconfident is caught by the same interval
    assert not low <= coverage(y, mean, 0.7 * var, 0.9) <= high
