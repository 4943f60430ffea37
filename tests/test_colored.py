"""kalman-colored: the exact MMSE predictor under moving-sum noise (brute-force Gaussian conditioning),
the plain KF for window 1, the generator's noise convention, and its empirical error."""

import numpy as np
import pytest
import torch

from mop.config import SystemConfig
from mop.filters.colored import ColoredNoiseKalmanPredictor, colored_kalman_filter
from mop.filters.kalman import kalman_filter
from mop.predictors import make_predictor
from mop.systems import generator, make_family
from mop.systems.linear import moving_sum_noise


def family(window, n=2, m=1):
    cfg = SystemConfig(
        family="colored-noise", state_dim=n, output_dim=m, color_window=window, noise_var_v=0.02
    )
    return make_family(cfg, dtype=torch.float64)


def test_window_one_is_the_plain_kalman_filter():
    traj = family(1, n=4, m=2).generate(20, 30, generator=generator(3))
    p = traj.params
    assert int(p.color_window[0]) == 1
    yhat, S = colored_kalman_filter(p.A, p.C, p.noise_var_w, p.noise_var_v, 1, traj.y, p.P0)
    ref = kalman_filter(p.A, p.C, p.Q, p.R, traj.y, P0=p.P0)
    torch.testing.assert_close(yhat, ref.yhat, atol=1e-10, rtol=0)
    torch.testing.assert_close(S, ref.S, atol=1e-10, rtol=0)


def test_generator_noise_convention():
    """The filter assumes e_t = eps_t + ... + eps_{t+W-1} over draws eps_0..eps_{T+W-1} (stationary from 0)
    and that each draw has the configured variance."""
    T, W, var = 7, 3, 0.3
    e = moving_sum_noise(2, T, 4, var, W, generator(5))
    eps = torch.randn(2, T + W, 4, generator=generator(5), dtype=torch.float64) * var**0.5
    ref = torch.stack([eps[:, t : t + W].sum(1) for t in range(T + 1)], dim=1)
    torch.testing.assert_close(e, ref, atol=1e-14, rtol=0)


def brute_force(A, C, P0, q, r, W, y):
    """E[y_t | y_{<t}] and Cov by conditioning the joint Gaussian of y_0..y_{T-1}, each written as a linear
    map of all draws d = [x_0; a_0..a_{T+W-2}; b_0..b_{T+W-2}]: x_{t+1} = A x_t + sum_{j<W} a_{t+j},
    y_t = C x_t + sum_{j<W} b_{t+j}."""
    n, m, T = A.shape[0], C.shape[0], y.shape[0]
    K = T + W - 1  # draws per noise
    D = n + K * n + K * m
    a = lambda k: slice(n + k * n, n + (k + 1) * n)  # noqa: E731
    b = lambda k: slice(n + K * n + k * m, n + K * n + (k + 1) * m)  # noqa: E731
    X = np.zeros((n, D))
    X[:, :n] = np.eye(n)
    rows = []
    for t in range(T):
        Y = C @ X
        for j in range(W):
            Y[:, b(t + j)] += np.eye(m)
        rows.append(Y)
        X = A @ X
        for j in range(W):
            X[:, a(t + j)] += np.eye(n)
    L = np.concatenate(rows)  # (T m, D)
    cov_d = np.zeros((D, D))
    cov_d[:n, :n] = P0
    cov_d[n : n + K * n, n : n + K * n] = q * np.eye(K * n)
    cov_d[n + K * n :, n + K * n :] = r * np.eye(K * m)
    cov = L @ cov_d @ L.T
    yv = y.reshape(-1)
    means, covs = [], []
    for t in range(T):
        now, past = slice(t * m, (t + 1) * m), slice(0, t * m)
        gain = np.linalg.solve(cov[past, past], cov[past, now]).T if t else np.zeros((m, 0))
        means.append(gain @ yv[past])
        covs.append(cov[now, now] - gain @ cov[past, now])
    return np.array(means), np.array(covs)


@pytest.mark.parametrize("W", [1, 2, 3])
def test_equals_brute_force_gaussian_conditioning(W):
    traj = family(W).generate(3, 6, generator=generator(11 + W))  # n = 2, m = 1, y_0..y_6
    p = traj.params
    yhat, S = colored_kalman_filter(p.A, p.C, p.noise_var_w, p.noise_var_v, W, traj.y, p.P0)
    for s in range(3):
        mean, cov = brute_force(
            p.A[s].numpy(), p.C[s].numpy(), p.P0[s].numpy(), 0.01, 0.02, W, traj.y[s].numpy()
        )
        np.testing.assert_allclose(yhat[s].numpy(), mean, atol=1e-8)
        np.testing.assert_allclose(S[s].numpy(), cov, atol=1e-8)


def test_empirical_error_matches_its_covariance_and_beats_the_white_kf():
    """Over N = 1000 systems (n = 3, m = 2, W = 5) the mean of ||y_t - yhat_t||^2 over t in [0, 20] is the
    mean of trace(S_t) within 5% (its relative standard error is about 1 / sqrt(N * 21 * m / 2) < 1%
    ignoring correlation over t, ~2% with it), and clearly below the white-noise KF's (which uses the summed
    variances and is ~2x worse at these settings)."""
    traj = family(5, n=3, m=2).generate(1000, 20, generator=generator(21))
    p = traj.params
    yhat, S = colored_kalman_filter(p.A, p.C, p.noise_var_w, p.noise_var_v, 5, traj.y, p.P0)
    mse = ((yhat - traj.y) ** 2).sum(-1).mean()
    expected = S.diagonal(dim1=-2, dim2=-1).sum(-1).mean()
    assert abs(mse / expected - 1) < 0.05, (mse, expected)
    white = ((make_predictor("kalman").predict(traj) - traj.y) ** 2).sum(-1).mean()
    assert mse < 0.8 * white, (mse, white)
    torch.testing.assert_close(ColoredNoiseKalmanPredictor().predict(traj), yhat)


@pytest.mark.parametrize(("window", "n", "m"), [(1, 3, 2), (2, 3, 2), (5, 4, 3)])
def test_shift_register_filter_equals_the_dense_augmented_filter(window, n, m, monkeypatch):
    """The structured filter (colored_filter, used by the predictor) against the generic Gaussian core on
    the dense augmented model: one-step, S_t and k-step means to 1e-10 over 100 steps, in chunks."""
    from mop.filters import colored
    from mop.filters.colored import colored_filter

    monkeypatch.setattr(colored, "CHUNK", 3)
    traj = family(window, n=n, m=m).generate(7, 100, generator=generator(window))
    p = traj.params
    args = (p.A, p.C, p.noise_var_w, p.noise_var_v, window)
    ref_yhat, ref_S = colored_kalman_filter(*args, traj.y, p.P0)
    means, S = colored_filter(*args, traj.y, p.P0, steps=1)
    torch.testing.assert_close(means[:, :, 0], ref_yhat, atol=1e-10, rtol=0)
    torch.testing.assert_close(S, ref_S, atol=1e-10, rtol=0)
    predictor = make_predictor("kalman-colored")
    fast, slow = predictor.forecast(traj, 6), predictor.reference_forecast(traj, 6)
    assert torch.equal(fast.isnan(), slow.isnan())
    torch.testing.assert_close(fast, slow, atol=1e-10, rtol=0, equal_nan=True)
    torch.testing.assert_close(predictor.predict(traj), ref_yhat, atol=1e-10, rtol=0)
