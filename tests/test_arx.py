"""ARX by RLS against a per-system numpy loop of the ridge closed form, equal to rls without inputs, its
forecasts against a plain numpy rollout, and its order selection against a direct argmin."""

import numpy as np
import pytest
import torch

from mop.config import SystemConfig
from mop.filters.arx import (
    adaptive_order_arx_predict,
    arx_forecast,
    arx_predict,
)
from mop.predictors import forecast, make_predictor, simulate
from mop.systems import generator, make_family
from tests.reference import filterpy_predict


def numpy_phi(y, u, p, q, s, offset=False):
    """[y_s..y_{s-p+1}, u_s..u_{s-q+1}] (and 1 with offset) for one system, zero before index 0."""
    lag = lambda a, j: a[s - j] if s - j >= 0 else np.zeros(a.shape[1])  # noqa: E731
    const = [np.ones(1)] if offset else []
    return np.concatenate([lag(y, j) for j in range(p)] + [lag(u, j) for j in range(q)] + const)


def numpy_arx(y, u, p, q, offset=False):
    """Per-system loop: yhat_t = theta_t^T phi_{t-1}, theta_t the ridge solution (lambda = 1) on the pairs
    (phi_{s-1}, y_s), s = r..t-1; start-up yhat_0 = 0, yhat_t = y_{t-1} (t <= r). Returns the thetas too."""
    T, m = y.shape
    r = max(p, q)
    out, thetas = np.zeros_like(y), {}
    for t in range(1, T):
        if t <= r:
            out[t] = y[t - 1]
            continue
        Phi = np.stack([numpy_phi(y, u, p, q, s - 1, offset) for s in range(r, t)])  # (N, d)
        theta = np.linalg.solve(np.eye(Phi.shape[1]) + Phi.T @ Phi, Phi.T @ y[r:t])  # (d, m)
        thetas[t] = theta
        out[t] = theta.T @ numpy_phi(y, u, p, q, t - 1, offset)
    return out, thetas


@pytest.fixture(scope="module")
def traj():
    cfg = SystemConfig(family="linear-inputs", state_dim=3, output_dim=2, input_dim=3)
    return make_family(cfg, torch.float64).generate(3, 25, generator=generator(0))


@pytest.mark.parametrize("p,q", [(1, 1), (2, 2), (3, 1), (1, 3)])
def test_arx_matches_the_ridge_closed_form(traj, p, q):
    yhat = arx_predict(traj.y, traj.u, p, q).numpy()
    for b in range(traj.num_systems):
        ref, _ = numpy_arx(traj.y[b].numpy(), traj.u[b].numpy(), p, q)
        np.testing.assert_allclose(yhat[b], ref, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("p,q", [(1, 1), (2, 3)])
def test_arx_offset_matches_the_ridge_closed_form_with_a_constant_regressor(traj, p, q):
    """offset: the closed form with a column of ones (penalized like the rest), on outputs shifted by 3
    (where the intercept matters: ARX without it is off by far more)."""
    y = traj.y + 3.0
    yhat = arx_predict(y, traj.u, p, q, offset=True).numpy()
    for b in range(traj.num_systems):
        ref, _ = numpy_arx(y[b].numpy(), traj.u[b].numpy(), p, q, offset=True)
        np.testing.assert_allclose(yhat[b], ref, rtol=1e-9, atol=1e-9)
    late = slice(15, None)
    err_with = ((arx_predict(y, traj.u, p, q, offset=True) - y)[:, late] ** 2).mean()
    err_without = ((arx_predict(y, traj.u, p, q) - y)[:, late] ** 2).mean()
    assert err_with < err_without


@pytest.mark.parametrize("with_inputs", [True, False])
def test_arx_offset_forecast_and_simulate_roll_out_with_the_constant(traj, with_inputs):
    """The constant is a known regressor in the rollout, as the inputs (with or without inputs): against
    the numpy recursion; and the registered arx-10-offset's simulate is its forecast from the context."""
    y, p = traj.y[0].numpy() + 3.0, 2
    u, q = (traj.u[0].numpy(), 2) if with_inputs else (np.zeros((len(y), 0)), 0)
    fc = arx_forecast(traj.y + 3.0, traj.u if with_inputs else None, p, 2, steps=4, offset=True).numpy()
    _, thetas = numpy_arx(y, u, p, q, offset=True)
    t = 12
    hist = y.copy()
    hist[t:] = np.nan
    for j in range(4):
        hist[t + j] = thetas[t].T @ numpy_phi(hist, u, p, q, t + j - 1, offset=True)
        np.testing.assert_allclose(fc[0, t, j], hist[t + j], rtol=1e-9, atol=1e-9)
    predictor = make_predictor("arx-10-offset")
    sim = simulate(predictor, traj, 20)
    torch.testing.assert_close(sim, forecast(predictor, traj, 6)[:, 20], rtol=1e-9, atol=1e-9)


def test_arx_offset_with_missing_outputs_is_the_ridge_on_complete_pairs():
    """The gap path takes the constant as a complete regressor: with one missing output at the end (no
    regressor filled in before it), predictions before it equal the complete-data ones."""
    cfg = SystemConfig(family="linear-inputs", state_dim=3, output_dim=2, input_dim=1)
    traj = make_family(cfg, torch.float64).generate(2, 20, generator=generator(1))
    y = traj.y + 1.0
    gappy = y.clone()
    gappy[:, -1, 0] = float("nan")
    full, gaps = arx_predict(y, traj.u, 2, 2, offset=True), arx_predict(gappy, traj.u, 2, 2, offset=True)
    torch.testing.assert_close(gaps, full, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("p,q", [(2, 2), (1, 3)])
def test_arx_forecast_iterates_the_fitted_model_with_known_inputs(traj, p, q):
    fc = arx_forecast(traj.y, traj.u, p, q, steps=4).numpy()
    y, u = traj.y[0].numpy(), traj.u[0].numpy()
    _, thetas = numpy_arx(y, u, p, q)
    for t in (max(p, q) + 1, 12, 21):
        hist = y.copy()
        hist[t:] = np.nan  # the outputs from t on are unknown: replaced by predictions as they come
        for j in range(4):
            if t + j >= len(y):
                assert np.isnan(fc[0, t, j]).all()
                continue
            hist[t + j] = thetas[t].T @ numpy_phi(hist, u, p, q, t + j - 1)
            np.testing.assert_allclose(fc[0, t, j], hist[t + j], rtol=1e-9, atol=1e-9)


def numpy_rollout(y, u, p, q, theta, t, steps):
    """The fitted ARX(p, q) `theta` iterated from origin t on its own predictions, one system: (steps, m)."""
    hist = y.copy()
    hist[t:] = np.nan  # the outputs from t on are unknown: replaced by predictions as they come
    for j in range(steps):
        hist[t + j] = theta.T @ numpy_phi(hist, u, p, q, t + j - 1)
    return hist[t : t + steps]


@pytest.mark.parametrize("p", [1, 2, 3])
def test_arx_without_inputs_is_the_ridge_ar_closed_form(traj, p):
    """u None: ARX(p) is output-only AR(p) by RLS, against the numpy ridge closed form with no input lags
    (predictions) and its numpy rollout (forecasts)."""
    no_u = np.zeros((traj.horizon + 1, 0))
    yhat, fc = arx_predict(traj.y, None, p).numpy(), arx_forecast(traj.y, None, p, steps=3).numpy()
    for b in range(traj.num_systems):
        y = traj.y[b].numpy()
        ref, thetas = numpy_arx(y, no_u, p, 0)
        np.testing.assert_allclose(yhat[b], ref, rtol=1e-9, atol=1e-9)
        for t in (p + 1, 12, 20):
            np.testing.assert_allclose(fc[b, t], numpy_rollout(y, no_u, p, 0, thetas[t], t, 3), rtol=1e-9)


def test_arx_best_picks_the_order_with_the_lowest_past_error(traj):
    P = 3
    yhat, order = adaptive_order_arx_predict(traj.y, traj.u, P)
    preds = [arx_predict(traj.y, traj.u, p, p).numpy() for p in range(1, P + 1)]
    y = traj.y.numpy()
    for b in range(traj.num_systems):
        for t in range(traj.horizon + 1):
            past = [((pr[b, P + 1 : t] - y[b, P + 1 : t]) ** 2).sum() for pr in preds]
            best = int(np.argmin(past))  # first minimum: the lowest order on ties
            assert order[b, t] == best + 1
            np.testing.assert_allclose(yhat[b, t], preds[best][b, t], rtol=0, atol=0)


def test_arx_beats_output_only_ar_and_last_on_linear_inputs():
    """MSE over t >= 20 on 100 linear-inputs systems, against independent references: the KF (filterpy with
    B u, the optimum) below ARX(2, 2), and output-only AR(2) (the numpy ridge closed form) and the last
    output above twice it. mop's "arx" is checked equal to the numpy ARX closed form on 10 of the systems, so
    the ordering is the method's, and arx-best (orders 1..5) is below half of AR(2) too."""
    traj = make_family(SystemConfig(family="linear-inputs"), torch.float64).generate(
        100, 50, generator=generator(5)
    )
    y, u = traj.y.numpy(), traj.u.numpy()
    arx = make_predictor("arx").predict(traj).numpy()
    for b in range(10):
        np.testing.assert_allclose(arx[b], numpy_arx(y[b], u[b], 2, 2)[0], rtol=1e-8, atol=1e-8)
    p = traj.params.map(torch.Tensor.numpy)
    kf = filterpy_predict(p.A, p.C, p.Q, p.R, y, np.zeros(p.A.shape[:2]), p.P0, p.B, u)
    no_u = np.zeros((y.shape[1], 0))
    ar2 = np.stack([numpy_arx(y[b], no_u, 2, 0)[0] for b in range(len(y))])
    last = np.concatenate([np.zeros_like(y[:, :1]), y[:, :-1]], axis=1)
    mse = lambda yhat: float(((yhat - y) ** 2).sum(-1)[:, 20:].mean())  # noqa: E731
    assert mse(kf) < mse(arx) < 0.5 * mse(last), (mse(kf), mse(arx), mse(last))
    assert mse(arx) < 0.5 * mse(ar2), (mse(arx), mse(ar2))
    assert mse(make_predictor("arx-best").predict(traj).numpy()) < 0.5 * mse(ar2)
    fc = forecast(make_predictor("arx"), traj, 3)
    assert torch.isfinite(fc[:, 20:40]).all()
