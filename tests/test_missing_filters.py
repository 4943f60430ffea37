"""Missing outputs (NaN in y) in the filters that know the system: KF against filterpy (update(None) for whole
missing steps, H_o / R_oo for partial ones) and against brute-force Gaussian conditioning on the measured
entries of the joint covariance; EKF/UKF on a linear model equal to the KF; the PF near the KF."""

import dataclasses

import numpy as np
import pytest
import torch

from mop.config import SystemConfig
from mop.filters.ekf import EKFPredictor
from mop.filters.kalman import kalman_filter, kalman_predict
from mop.filters.particle import ParticleFilterPredictor
from mop.filters.ukf import UKFPredictor
from mop.predictors import make_predictor
from mop.systems import generator, make_family
from tests.reference import (
    filterpy_distribution_gaps,
    filterpy_predict_gaps,
    joint_gaussian_predict,
    linear_traj,
    monte_carlo_bias,
)
from tests.test_kalman import random_spd, random_system, simulate


def with_gaps(traj, rate=0.3, whole_steps=(), seed=0):
    """traj with a random `rate` of the outputs set to NaN (not at t = 0) and every channel at whole_steps."""
    y = traj.y.clone()
    g = torch.Generator().manual_seed(seed)
    drop = torch.rand(y.shape, generator=g, dtype=torch.float64) < rate
    drop[:, 0] = False
    drop[:, list(whole_steps)] = True
    y[drop] = float("nan")
    return dataclasses.replace(traj, y=y)


def test_whole_missing_steps_equal_filterpy_update_none():
    rng = np.random.default_rng(0)
    A, C, Q, R = random_system(rng, 3, 3, 2)
    y = simulate(rng, A, C, Q, R, 20)
    y[:, [3, 4, 5, 11, 17]] = np.nan  # whole steps: filterpy's update(None)
    y[1, 8] = np.nan  # one system only
    x0, P0 = rng.normal(size=(3, 3)), random_spd(rng, 3, 3, scale=1.0)
    ref = filterpy_predict_gaps(A, C, Q, R, y, x0, P0)
    np.testing.assert_allclose(kalman_predict(A, C, Q, R, y, x0, P0), ref, atol=1e-9, rtol=0)


@pytest.mark.parametrize("n,m", [(3, 2), (2, 4)])
def test_single_missing_channels_equal_joint_gaussian_conditioning(n, m):
    rng = np.random.default_rng(n + m)
    A, C, Q, R = random_system(rng, 2, n, m)
    P0 = random_spd(rng, 2, n, scale=1.0)
    y = simulate(rng, A, C, Q, R, 9, P0=P0)
    y[rng.random(y.shape) < 0.35] = np.nan  # single channels here and there, some whole steps by chance
    yhat = kalman_predict(A, C, Q, R, y, np.zeros((2, n)), P0)
    for b in range(2):
        ref = joint_gaussian_predict(A[b], C[b], Q[b], R[b], P0[b], y[b])
        np.testing.assert_allclose(yhat[b], ref, atol=1e-8, rtol=0)
    ref_fp = filterpy_predict_gaps(A, C, Q, R, y, np.zeros((2, n)), P0)
    np.testing.assert_allclose(yhat, ref_fp, atol=1e-9, rtol=0)


@pytest.mark.parametrize("partial", [False, True])
def test_predictive_covariance_across_missing_outputs_equals_filterpy(partial):
    # S_t = C P_t C^T + R of filterpy's prior, with whole steps skipped (update(None)) and, for `partial`,
    # single channels conditioned on the measured ones only: the covariance after a gap grows, and is
    # that of all of y_t at a step where some channels are missing
    rng = np.random.default_rng(7 + partial)
    A, C, Q, R = random_system(rng, 3, 3, 2)
    y = simulate(rng, A, C, Q, R, 24)
    y[:, [4, 5, 6, 15]] = np.nan
    if partial:
        y[rng.random(y.shape) < 0.3] = np.nan
    x0, P0 = rng.normal(size=(3, 3)), random_spd(rng, 3, 3, scale=1.0)
    ref_mean, ref_S = filterpy_distribution_gaps(A, C, Q, R, y, x0, P0)
    out = kalman_filter(A, C, Q, R, y, x0, P0)
    np.testing.assert_allclose(out.yhat, ref_mean, atol=1e-9, rtol=0)
    np.testing.assert_allclose(out.S, ref_S, atol=1e-9, rtol=1e-9)


def test_kalman_predictor_variance_with_gaps_equals_filterpy():
    traj = with_gaps(linear_traj(num_systems=3, horizon=20), whole_steps=(7, 8))
    _, var = make_predictor("kalman").predict_distribution(traj)
    p = {k: v.numpy() for k, v in traj.params.as_dict().items()}
    m0 = np.zeros((3, p["A"].shape[-1]))
    _, ref_S = filterpy_distribution_gaps(p["A"], p["C"], p["Q"], p["R"], traj.y.numpy(), m0, p["P0"])
    np.testing.assert_allclose(var.numpy(), np.diagonal(ref_S, axis1=-2, axis2=-1), atol=1e-9, rtol=1e-9)


def test_kalman_predictor_distribution_with_gaps_is_finite_and_skips_missing():
    traj = with_gaps(linear_traj(num_systems=4, horizon=25), whole_steps=(7,))
    mean, var = make_predictor("kalman").predict_distribution(traj)
    assert torch.isfinite(mean).all() and (var > 0).all()
    # the prior at t = 8 after a whole missing step is the two-step prediction from t = 6
    fc = make_predictor("kalman").forecast(traj, 3)
    torch.testing.assert_close(mean[:, 8], fc[:, 7, 1], rtol=0, atol=1e-12)


def test_ekf_and_ukf_on_a_linear_model_with_gaps_equal_the_kalman_filter():
    traj = with_gaps(linear_traj(seed=1), whole_steps=(4, 5))
    kf = make_predictor("kalman").predict(traj)
    torch.testing.assert_close(EKFPredictor().predict(traj), kf, rtol=0, atol=1e-9)
    torch.testing.assert_close(UKFPredictor().predict(traj), kf, rtol=0, atol=1e-8)


def gappy_systems(case: str):
    """Seeded linear systems with gaps: scalar (n = m = 1, 30% missing and a whole missing step), or n = m = 2
    with correlated R (40% missing: one channel measured, the other not, where the likelihood of the
    measured is N(y_o; C_o x, R_oo), not R^-1's block)."""
    if case == "scalar":
        config = SystemConfig(family="linear", state_dim=1, output_dim=1, noise_var_w=0.1, noise_var_v=0.1)
        traj = make_family(config, torch.float64).generate(120, 15, generator=generator(2))
        return with_gaps(traj, rate=0.3, whole_steps=(6,))
    config = SystemConfig(family="linear", state_dim=2, output_dim=2, noise_var_w=0.1, noise_var_v=0.1)
    traj = make_family(config, torch.float64).generate(100, 12, generator=generator(5))
    R = 0.2 * torch.tensor([[1.0, 0.9], [0.9, 1.0]], dtype=torch.float64)
    params = dataclasses.replace(traj.params, R=R.expand(100, 2, 2).clone())
    return with_gaps(dataclasses.replace(traj, params=params), 0.4)


@pytest.mark.parametrize("case", ["scalar", "correlated"])
def test_particle_filter_with_gaps_is_the_kalman_filter_within_its_monte_carlo_error(case):
    """With missing outputs the PF still converges to the KF (exact on linear-Gaussian systems): two runs
    with independent draws, each minus the KF, have a mean cross product (the squared bias) within 3
    standard errors of 0 over the independent systems (tests/reference.monte_carlo_bias)."""
    traj = gappy_systems(case)
    kf = make_predictor("kalman").predict(traj).numpy()
    a, b = (ParticleFilterPredictor(4000, seed=s).predict(traj).numpy() - kf for s in (0, 1))
    bias2, se = monte_carlo_bias(a, b)
    assert bias2 < 3 * se, (bias2, se)
    assert np.mean(a**2) < 1e-3 * np.nanmean((traj.y.numpy() - kf) ** 2)  # and small


def test_no_gaps_takes_the_unchanged_path():
    traj = linear_traj()
    assert traj.observed is None and traj.num_missing == 0
    gappy = with_gaps(traj)
    assert gappy.observed is not None and gappy.num_missing == int((~gappy.observed).sum())
