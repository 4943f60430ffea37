"""Matrix RLS equals a textbook loop and the closed-form ridge solution at every step; adaptive order
finds AR(p)."""

import numpy as np
import pytest
import torch

from mop.filters.rls import AdaptiveOrderRLSPredictor, RLSPredictor, adaptive_order_rls_predict, rls_predict
from mop.systems.base import Trajectories


def ridge_reference(y: np.ndarray, order: int) -> np.ndarray:
    """yhat_t = theta_t^T phi_{t-1}, theta_t = (I + sum phi phi^T)^{-1} sum phi y^T over the pairs
    (phi_{s-1}, y_s), s = p..t-1, phi_s = [y_s; ...; y_{s-p+1}] (p*m), solved from scratch at each t;
    yhat_0 = 0 and yhat_t = y_{t-1} for 1 <= t <= p."""
    B, T, m = y.shape
    out = np.zeros_like(y)
    for b in range(B):
        phi = lambda s, b=b: np.concatenate([y[b, s - j] for j in range(order)])  # noqa: E731
        for t in range(1, T):
            if t <= order:
                out[b, t] = y[b, t - 1]
                continue
            X = np.array([phi(s - 1) for s in range(order, t)])  # (t-p, p*m)
            theta = np.linalg.solve(np.eye(order * m) + X.T @ X, X.T @ y[b, order:t])  # (p*m, m)
            out[b, t] = theta.T @ phi(t - 1)
    return out


def textbook_rls(y: np.ndarray, order: int) -> np.ndarray:
    """Plain per-system loop of the RLS recursion (P0 = I, theta0 = 0, forgetting 1), written out."""
    B, T, m = y.shape
    d = order * m
    out = np.zeros_like(y)
    for b in range(B):
        theta, P = np.zeros((d, m)), np.eye(d)
        for t in range(1, T):
            if t <= order:
                out[b, t] = y[b, t - 1]
                continue
            prev = np.concatenate([y[b, t - 2 - j] for j in range(order)])  # phi_{t-2}, target y_{t-1}
            gain = P @ prev / (1.0 + prev @ P @ prev)
            theta = theta + np.outer(gain, y[b, t - 1] - theta.T @ prev)
            P = P - np.outer(gain, prev @ P)
            out[b, t] = theta.T @ np.concatenate([y[b, t - 1 - j] for j in range(order)])
    return out


@pytest.mark.parametrize("order", [1, 2, 3])
def test_rls_equals_ridge_closed_form_and_textbook_loop(order):
    y = np.random.default_rng(order).normal(size=(3, 25, 2)).cumsum(1) * 0.3
    yhat = rls_predict(torch.from_numpy(y), order).numpy()
    np.testing.assert_allclose(yhat, ridge_reference(y, order), atol=1e-9)
    np.testing.assert_allclose(yhat, textbook_rls(y, order), atol=1e-9)


def test_rls_is_matrix_ar_startup_of_the_authors():
    """yhat_0 = 0, yhat_1 = y_0, yhat_2 = y_1; yhat_3 uses the cross-output pair (phi_1 = [y_1; y_0], y_2):
    theta = phi (1 + |phi|^2)^{-1} y_2^T, so yhat_3 = y_2 (phi_1^T phi_2) / (1 + |phi_1|^2)."""
    y = torch.tensor([[[1.0, 0.0], [0.0, 2.0], [3.0, -1.0], [0.5, 0.5]]], dtype=torch.float64)
    yhat = rls_predict(y, 2)[0]
    torch.testing.assert_close(yhat[:3], torch.stack([torch.zeros(2), y[0, 0], y[0, 1]]).double())
    phi1, phi2 = torch.cat([y[0, 1], y[0, 0]]), torch.cat([y[0, 2], y[0, 1]])
    torch.testing.assert_close(yhat[3], y[0, 2] * (phi1 @ phi2) / (1 + phi1 @ phi1))


def ar_process(rng, coeffs, B, T, noise=0.1):
    y = np.zeros((B, T))
    for t in range(T):
        y[:, t] = sum(
            c * y[:, t - 1 - j] for j, c in enumerate(coeffs) if t - 1 - j >= 0
        ) + noise * rng.normal(size=B)
    return y[..., None]  # (B, T, 1)


def test_adaptive_order_picks_true_order():
    """AR(3) with poles 0.9, -0.8, 0.7: orders 1 and 2 miss the dynamics; higher orders pay for the extra
    estimation noise (predictive least squares is consistent, so this grows with T). With T = 1000 the true
    order is chosen for ~78% of 200 systems (seed 0); we require more than 70% and almost never too low."""
    coeffs = -np.poly([0.9, -0.8, 0.7])[1:]
    y = ar_process(np.random.default_rng(0), coeffs, 200, 1000)
    _, order = adaptive_order_rls_predict(torch.from_numpy(y), max_order=5)
    chosen = order[:, -1].numpy()
    assert (chosen == 3).mean() > 0.7, np.bincount(chosen)
    assert (chosen < 3).mean() < 0.05


def test_adaptive_yhat_is_the_chosen_orders_prediction():
    """rls-best at t: the order p in 1..3 whose numpy ridge closed-form AR(p) predictions have the lowest
    summed squared error over s in [P + 1, t) (P = 3; the first on ties, up to rounding: orders whose
    errors are equal in exact arithmetic may differ in the last digit), and that order's prediction."""
    y = ar_process(np.random.default_rng(1), [0.5, 0.3], 5, 40)
    yhat, order = adaptive_order_rls_predict(torch.from_numpy(y), max_order=3)
    preds = [ridge_reference(y, p) for p in (1, 2, 3)]
    for b in range(5):
        for t in range(40):
            past = np.array([((pr[b, 4:t] - y[b, 4:t]) ** 2).sum() for pr in preds])
            lowest = np.flatnonzero(past <= past.min() * (1 + 1e-9))  # the minimum, with rounding ties
            chosen = int(order[b, t]) - 1
            assert chosen in lowest, (b, t, past)
            np.testing.assert_allclose(yhat[b, t].numpy(), preds[chosen][b, t], rtol=1e-9, atol=1e-12)


def test_predictors_follow_protocol_and_dtype():
    y = torch.randn(2, 10, 3, generator=torch.Generator().manual_seed(0))
    traj = Trajectories(y=y)
    for pred in (RLSPredictor(), AdaptiveOrderRLSPredictor()):
        out = pred.predict(traj)
        assert out.shape == y.shape and out.dtype == y.dtype
    torch.testing.assert_close(RLSPredictor().predict(traj)[:, 1:3], y[:, 0:2])  # copies up to t = p
