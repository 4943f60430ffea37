"""mop.metrics against plain numpy formulas, closed forms and statistical properties."""

import math

import numpy as np
import pytest
import torch

from mop import metrics


def test_errors_and_curves_match_numpy():
    g = torch.Generator().manual_seed(0)
    y, yhat = torch.randn(7, 11, 3, generator=g), torch.randn(7, 11, 3, generator=g)
    e = metrics.errors(yhat, y)
    ref = np.sqrt(((yhat.numpy() - y.numpy()) ** 2).sum(-1))
    np.testing.assert_allclose(e, ref, rtol=1e-6)
    c = metrics.error_curves(e)
    np.testing.assert_allclose(c["error"], ref.mean(0), rtol=1e-6)
    np.testing.assert_allclose(c["squared_error"], (ref**2).mean(0), rtol=1e-6)
    np.testing.assert_allclose(c["std"], ref.std(0), rtol=1e-6)


def test_window_mean():
    curve = np.arange(51.0)
    assert metrics.window_mean(curve, 20, 51) == pytest.approx(curve[20:].mean())
    assert metrics.window_mean(curve, 1, 11) == pytest.approx(5.5)
    assert metrics.window_mean(curve, 20, 1000) == pytest.approx(35.0)


def test_mse_ratio_ci_covers_true_ratio():
    """Errors with known scale: e_num ~ |N(0, 2)|, e_den ~ |N(0, 1)| -> MSE ratio 2; 95% CI covers ~95%."""
    rng = np.random.default_rng(1)
    hits, trials = 0, 200
    for trial in range(trials):
        e_den = np.abs(rng.normal(size=(100, 5)))
        e_num = np.abs(rng.normal(scale=math.sqrt(2), size=(100, 5)))
        r, low, high = metrics.mse_ratio_ci(e_num, e_den, 0, 5, num_boot=300, seed=trial)
        assert low <= r <= high
        hits += low <= 2.0 <= high
    assert 0.88 <= hits / trials <= 0.99  # binomial sd at 0.95 over 200 trials is 0.015


def test_mse_ratio_point_estimate_and_seed():
    rng = np.random.default_rng(2)
    a, b = rng.random((30, 8)), rng.random((30, 8))
    r, *ci = metrics.mse_ratio_ci(a, b, 2, 6, seed=3)
    assert r == pytest.approx((a[:, 2:6] ** 2).sum() / (b[:, 2:6] ** 2).sum())
    assert metrics.mse_ratio_ci(a, b, 2, 6, seed=3)[1:] == tuple(ci)


def test_gaussian_nll_matches_torch_normal():
    g = torch.Generator().manual_seed(4)
    y, mu = torch.randn(5, 6, 2, generator=g), torch.randn(5, 6, 2, generator=g)
    var = torch.rand(5, 6, 2, generator=g) + 0.1
    ref = -torch.distributions.Normal(mu, var.sqrt()).log_prob(y).mean()
    assert metrics.gaussian_nll(y, mu, var) == pytest.approx(float(ref), rel=1e-6)


@pytest.mark.parametrize("level", [0.5, 0.9, 0.95])
def test_coverage_of_known_gaussian_errors(level):
    """A predictor whose errors are exactly N(0, var): coverage equals the level within 4 binomial sd."""
    g = torch.Generator().manual_seed(5)
    var = torch.rand(200, 50, 3, generator=g) * 2 + 0.05
    mu = torch.randn(200, 50, 3, generator=g)
    y = mu + var.sqrt() * torch.randn(200, 50, 3, generator=g)
    n = y.numel()
    assert abs(metrics.coverage(y, mu, var, level) - level) < 4 * math.sqrt(level * (1 - level) / n)
    assert metrics.coverage(y, mu, var / 4, level) < level - 0.1  # overconfident variance must show


def test_loglog_slope_recovers_power_law_and_stderr():
    x = np.array([100.0, 400, 1600, 6400])
    slope, intercept, se = metrics.loglog_slope(x, 3 * x**-0.5)
    assert slope == pytest.approx(-0.5) and math.exp(intercept) == pytest.approx(3) and se < 1e-8
    noisy = 3 * x**-0.5 * np.exp(np.array([0.1, -0.1, 0.1, -0.1]))
    _, _, se = metrics.loglog_slope(x, noisy)
    lx = np.log(x)
    fit = np.polyfit(lx, np.log(noisy), 1, cov=True)
    assert se == pytest.approx(math.sqrt(fit[1][0, 0]), rel=1e-6)


def test_matrix_power_ratio_numpy():
    g = torch.Generator().manual_seed(6)
    A = torch.randn(4, 3, 3, generator=g, dtype=torch.float64) * 0.5
    out = metrics.matrix_power_ratio(A, 5)
    An = A.numpy()
    rho = np.abs(np.linalg.eigvals(An)).max(-1)
    pairs = list(zip(An, rho, strict=True))
    power = np.linalg.matrix_power
    ref = [np.mean([np.linalg.norm(power(a, k), 2) / r**k for a, r in pairs]) for k in range(5)]
    np.testing.assert_allclose(out, ref, rtol=1e-8)
