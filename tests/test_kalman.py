"""Kalman filter against filterpy step by step, DARE against scipy, calibration, switching variants."""

import numpy as np
import pytest
import scipy.linalg
import torch
from filterpy.kalman import KalmanFilter

from mop.filters.kalman import (
    innovation_floor,
    kalman_filter,
    kalman_predict,
    optimal_mse_curve,
    solve_filter_dare,
    steady_state_gain,
    steady_state_predict,
)
from mop.predictors import make_predictor
from mop.systems.base import Trajectories
from mop.systems.switching import SwitchingParams
from tests.reference import filterpy_predict


def random_spd(rng, B, d, scale=0.1):
    M = rng.normal(size=(B, d, d))
    return scale * (M @ M.transpose(0, 2, 1) / d + 0.5 * np.eye(d))


def random_system(rng, B, n, m, rho=0.9):
    A = rng.normal(size=(B, n, n))
    A *= rho / np.abs(np.linalg.eigvals(A)).max(-1)[:, None, None]
    return A, rng.normal(size=(B, m, n)), random_spd(rng, B, n), random_spd(rng, B, m)


def simulate(rng, A, C, Q, R, T, P0=None):
    B, n, m = A.shape[0], A.shape[-1], C.shape[1]
    P0 = np.broadcast_to(np.eye(n), (B, n, n)) if P0 is None else P0
    x = np.einsum("bij,bj->bi", np.linalg.cholesky(P0), rng.normal(size=(B, n)))
    Lq, Lr, ys = np.linalg.cholesky(Q), np.linalg.cholesky(R), []
    for _ in range(T):
        ys.append(np.einsum("bij,bj->bi", C, x) + np.einsum("bij,bj->bi", Lr, rng.normal(size=(B, m))))
        x = np.einsum("bij,bj->bi", A, x) + np.einsum("bij,bj->bi", Lq, rng.normal(size=(B, n)))
    return np.stack(ys, axis=1)


@pytest.mark.parametrize("n,m", [(1, 1), (3, 2), (4, 4), (2, 5)])
@pytest.mark.parametrize("as_torch", [False, True])
def test_kalman_matches_filterpy(n, m, as_torch):
    rng = np.random.default_rng(n * 10 + m)
    A, C, Q, R = random_system(rng, 3, n, m)
    y = simulate(rng, A, C, Q, R, 20)
    x0, P0 = rng.normal(size=(3, n)), random_spd(rng, 3, n, scale=1.0)
    ref = filterpy_predict(A, C, Q, R, y, x0, P0)
    args = [torch.from_numpy(a) for a in (A, C, Q, R, y, x0, P0)] if as_torch else [A, C, Q, R, y, x0, P0]
    yhat = kalman_predict(*args)
    assert isinstance(yhat, torch.Tensor) == as_torch
    np.testing.assert_allclose(np.asarray(yhat), ref, atol=1e-6, rtol=0)


def test_kalman_defaults_zero_mean_identity_cov():
    rng = np.random.default_rng(1)
    A, C, Q, R = random_system(rng, 2, 3, 2)
    y = simulate(rng, A, C, Q, R, 10)
    ref = filterpy_predict(A, C, Q, R, y, np.zeros((2, 3)), np.broadcast_to(np.eye(3), (2, 3, 3)).copy())
    np.testing.assert_allclose(kalman_predict(A, C, Q, R, y), ref, atol=1e-6)


@pytest.mark.parametrize("n,m", [(2, 1), (4, 2), (6, 3)])
def test_dare_matches_scipy(n, m):
    rng = np.random.default_rng(n)
    A, C, Q, R = random_system(rng, 4, n, m, rho=1.05)  # unstable A still has a stabilizing solution
    P = solve_filter_dare(*(torch.from_numpy(a) for a in (A, C, Q, R))).numpy()
    K, _ = steady_state_gain(*(torch.from_numpy(a) for a in (A, C, Q, R)))
    for b in range(4):
        ref = scipy.linalg.solve_discrete_are(A[b].T, C[b].T, Q[b], R[b])
        np.testing.assert_allclose(P[b], ref, rtol=1e-8, atol=1e-10)
        K_ref = A[b] @ ref @ C[b].T @ np.linalg.inv(C[b] @ ref @ C[b].T + R[b])
        np.testing.assert_allclose(K[b].numpy(), K_ref, rtol=1e-8, atol=1e-10)


def test_time_varying_covariance_converges_to_dare():
    rng = np.random.default_rng(3)
    A, C, Q, R = random_system(rng, 3, 3, 2)
    res = kalman_filter(A, C, Q, R, simulate(rng, A, C, Q, R, 200))
    P = solve_filter_dare(*(torch.from_numpy(a) for a in (A, C, Q, R))).numpy()
    np.testing.assert_allclose(res.S[:, -1], C @ P @ C.transpose(0, 2, 1) + R, rtol=1e-8)
    # and the steady-state predictor agrees with the time-varying filter once converged (same data)
    y = torch.from_numpy(simulate(rng, A, C, Q, R, 300))
    K, _ = steady_state_gain(*(torch.from_numpy(a) for a in (A, C, Q, R)))
    ss = steady_state_predict(torch.from_numpy(A), torch.from_numpy(C), K, y)
    np.testing.assert_allclose(ss[:, -50:], kalman_predict(A, C, Q, R, y.numpy())[:, -50:], atol=1e-6)


def test_innovation_covariance_is_calibrated():
    """Innovations e_t = y_t - yhat_t have covariance S_t: whitened e has identity covariance.
    2000 systems x 30 steps x m=2 -> 120000 whitened samples; each entry of the sample covariance
    has standard error about 1/sqrt(60000) ~ 0.004, so a tolerance of 0.03 is about 7 standard errors."""
    rng = np.random.default_rng(4)
    A, C, Q, R = random_system(rng, 2000, 3, 2)
    P0 = random_spd(rng, 2000, 3, scale=1.0)
    y = simulate(rng, A, C, Q, R, 30, P0)
    res = kalman_filter(A, C, Q, R, y, P0=P0)
    white = np.linalg.solve(np.linalg.cholesky(res.S), (y - res.yhat)[..., None])[..., 0].reshape(-1, 2)
    np.testing.assert_allclose(white.T @ white / len(white), np.eye(2), atol=0.03)
    np.testing.assert_allclose(white.mean(0), 0, atol=0.02)


def _switching_traj(rng, B=4, n=3, m=2, T=30, s=12):
    A, C, Q, R = random_system(rng, B, n, m)
    A2, C2, _, _ = random_system(rng, B, n, m)
    y = simulate(rng, A, C, Q, R, T + 1)
    arrays = {k: torch.from_numpy(v) for k, v in dict(A=A, C=C, Q=Q, R=R, A2=A2, C2=C2).items()}
    per_system = torch.ones(B, dtype=torch.float64)  # the per-draw variances: not read by the filters here
    params = SwitchingParams(
        **arrays,
        P0=torch.eye(n, dtype=torch.float64).expand(B, n, n),
        noise_var_w=per_system,
        noise_var_v=per_system,
        color_window=torch.ones(B, dtype=torch.long),
        switch_time=torch.full((B,), s, dtype=torch.long),
    )
    return Trajectories(y=torch.from_numpy(y), params=params, family="switching")


def test_switch_aware_kalman_equals_kf_with_system2_after_switch():
    """Before s: a KF on system 1. From s: a KF on system 2 whose prior is system 1's prediction of x_s."""
    rng, s = np.random.default_rng(5), 12
    traj = _switching_traj(rng, s=s)
    p = traj.params.map(torch.Tensor.numpy)
    y = traj.y.numpy()
    yhat = make_predictor("kalman").predict(traj).numpy()  # the switching family's model knows the switch
    keep = make_predictor("kalman-system1").predict(traj).numpy()  # the authors' baseline keeps system 1
    np.testing.assert_allclose(
        yhat[:, :s],
        filterpy_predict(p.A, p.C, p.Q, p.R, y[:, :s], np.zeros((4, 3)), p.P0),
        atol=1e-6,
    )
    np.testing.assert_allclose(
        keep, filterpy_predict(p.A, p.C, p.Q, p.R, y, np.zeros((4, 3)), p.P0), atol=1e-6
    )
    # system 1's prior for x_s, built with filterpy on the first s outputs
    x_s, P_s = np.zeros((4, 3)), np.zeros((4, 3, 3))
    for b in range(4):
        kf = KalmanFilter(dim_x=3, dim_z=2)
        kf.F, kf.H, kf.Q, kf.R, kf.x, kf.P = (
            p.A[b],
            p.C[b],
            p.Q[b],
            p.R[b],
            np.zeros(3),
            np.eye(3),
        )
        for t in range(s):
            kf.update(y[b, t])
            kf.predict()
        x_s[b], P_s[b] = kf.x, kf.P
    ref = filterpy_predict(p.A2, p.C2, p.Q, p.R, y[:, s:], x_s, P_s)
    np.testing.assert_allclose(yhat[:, s:], ref, atol=1e-6)


def test_bad_shapes_raise_moperror():
    from mop.errors import MopError

    with pytest.raises(MopError, match="C has shape"):
        kalman_predict(
            np.eye(2)[None], np.ones((1, 2, 3)), np.eye(2)[None], np.eye(2)[None], np.zeros((1, 5, 2))
        )


def test_innovation_floor_is_the_large_t_limit_of_the_optimal_mse_curve():
    rng = np.random.default_rng(7)
    A, C, Q, R = random_system(rng, 4, 4, 2)
    floor = innovation_floor(A, C, Q, R)
    curve = optimal_mse_curve(A, C, Q, R, horizon=300)
    assert curve.shape == (4, 301)
    torch.testing.assert_close(curve[:, -1], floor, atol=1e-9, rtol=1e-9)
    assert (curve[:, 0] > floor).all()  # P0 = I is more uncertain than the steady state here
    At, Ct, Qt, Rt = (torch.from_numpy(M) for M in (A, C, Q, R))
    P = solve_filter_dare(At, Ct, Qt, Rt)  # the batched doubling solver gives the same floor
    torch.testing.assert_close((Ct @ P @ Ct.mT + Rt).diagonal(dim1=-2, dim2=-1).sum(-1), floor)
    for b in range(4):  # independent: the textbook Riccati recursion in numpy, P_0 = I
        P, traces = np.eye(4), []
        for _ in range(301):
            S = C[b] @ P @ C[b].T + R[b]
            traces.append(np.trace(S))
            P = A[b] @ (P - P @ C[b].T @ np.linalg.solve(S, C[b] @ P)) @ A[b].T + Q[b]
        np.testing.assert_allclose(curve[b].numpy(), traces, rtol=1e-9)


def test_optimal_mse_curve_matches_the_empirical_kf_error():
    """Over N = 2000 paper-like linear systems, the empirical mean of ||y_t - yhat_t||^2 of the KF at
    t = 0, 1, 2, 5, 10 and averaged over [20, 50) is the mean of trace(S_t) within 6% (about 4 standard
    errors: ||e_t||^2 / trace(S_t) has mean 1 and relative std ~ sqrt(2 / m_eff) ~ 0.8 for m = 5, so over N
    systems ~ 0.018 per t; the [20, 50) average is tighter, checked to 3%). sqrt of the curve is at or above
    the mean ||e_t||_2 (Jensen), as the docstring states."""
    from mop.config import SystemConfig
    from mop.systems import generator, make_family

    traj = make_family(SystemConfig(), dtype=torch.float64).generate(2000, 50, generator=generator(99))
    p = traj.params
    curve = optimal_mse_curve(p.A, p.C, p.Q, p.R, horizon=50, P0=p.P0)  # (N, 51)
    err = kalman_predict(p.A, p.C, p.Q, p.R, traj.y, P0=p.P0) - traj.y
    mse, expected = (err**2).sum(-1).mean(0), curve.mean(0)  # (51,)
    for t in (0, 1, 2, 5, 10):
        assert abs(mse[t] / expected[t] - 1) < 0.06, (t, mse[t], expected[t])
    assert abs(mse[20:50].mean() / expected[20:50].mean() - 1) < 0.03
    assert (err.norm(dim=-1).mean(0) <= curve.sqrt().mean(0) * 1.02).all()


def test_expected_norm_is_the_chi_mean_and_matches_the_kf_mean_error():
    """E||e|| for e ~ N(0, s^2 I_m) is s sqrt(2) Gamma((m+1)/2) / Gamma(m/2) (the chi distribution's mean);
    for a correlated S the Monte Carlo value is rotation invariant; over 2000 linear systems the KF's
    empirical mean ||y_t - yhat_t|| matches the mean of E||e_t||, e_t ~ N(0, S_t), within 2% at t >= 20."""
    from math import gamma, sqrt

    from mop.config import SystemConfig
    from mop.filters.kalman import expected_norm, optimal_covariances
    from mop.systems import generator, make_family

    for m, s in ((1, 0.3), (5, 2.0)):
        chi = s * sqrt(2) * gamma((m + 1) / 2) / gamma(m / 2)
        value = float(expected_norm(torch.eye(m, dtype=torch.float64) * s**2, num_samples=200_000))
        assert abs(value / chi - 1) < 0.01, (m, value, chi)
    traj = make_family(SystemConfig(), dtype=torch.float64).generate(2000, 50, generator=generator(5))
    p = traj.params
    S = optimal_covariances(p.A, p.C, p.Q, p.R, horizon=50, P0=p.P0)  # (N, 51, m, m)
    curve = optimal_mse_curve(p.A, p.C, p.Q, p.R, horizon=50, P0=p.P0)
    torch.testing.assert_close(S.diagonal(dim1=-2, dim2=-1).sum(-1), curve, rtol=0, atol=0)
    norm = expected_norm(S, num_samples=300).mean(0)  # (51,)
    err = (kalman_predict(p.A, p.C, p.Q, p.R, traj.y, P0=p.P0) - traj.y).norm(dim=-1)
    assert abs(err[:, 20:].mean() / norm[20:].mean() - 1) < 0.02
    assert (norm < curve.mean(0).sqrt()).all()  # below the RMS (Jensen): the old line sat above the KF
