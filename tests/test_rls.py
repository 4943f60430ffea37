"""RLS equals the closed-form ridge least-squares solution at every step; adaptive order finds AR(p)."""

import numpy as np
import pytest
import torch

from mop.filters.rls import AdaptiveOrderRLSPredictor, RLSPredictor, adaptive_order_rls_predict, rls_predict
from mop.systems.base import Trajectories


def ridge_reference(y: np.ndarray, order: int) -> np.ndarray:
    """yhat_t = theta_t^T phi_{t-1}, theta_t = (I + sum phi phi^T)^{-1} sum phi y over the pairs
    (phi_{s-1}, y_s), s = p..t-1, solved from scratch at each t; copy of y_{t-1} for t < p."""
    B, T, m = y.shape
    out = np.zeros_like(y)
    for b in range(B):
        for i in range(m):
            z = y[b, :, i]
            phi = lambda s, z=z: z[s - order + 1 : s + 1][::-1]  # noqa: E731  [z_s, ..., z_{s-p+1}]
            for t in range(1, T):
                if t < order:
                    out[b, t, i] = z[t - 1]
                    continue
                X = np.array([phi(s - 1) for s in range(order, t)]).reshape(-1, order)
                theta = np.linalg.solve(np.eye(order) + X.T @ X, X.T @ z[order:t])
                out[b, t, i] = theta @ phi(t - 1)
    return out


@pytest.mark.parametrize("order", [1, 2, 3])
def test_rls_equals_ridge_closed_form(order):
    y = np.random.default_rng(order).normal(size=(3, 25, 2)).cumsum(1) * 0.3
    np.testing.assert_allclose(
        rls_predict(torch.from_numpy(y), order).numpy(), ridge_reference(y, order), atol=1e-9
    )


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
    y = torch.from_numpy(ar_process(np.random.default_rng(1), [0.5, 0.3], 5, 40))
    yhat, order = adaptive_order_rls_predict(y, max_order=3)
    for b in range(5):
        for t in range(40):
            assert torch.allclose(yhat[b, t], rls_predict(y[b : b + 1], int(order[b, t]))[0, t])


def test_predictors_follow_protocol_and_dtype():
    y = torch.randn(2, 10, 3, generator=torch.Generator().manual_seed(0))
    traj = Trajectories(y=y)
    for pred in (RLSPredictor(), AdaptiveOrderRLSPredictor()):
        out = pred.predict(traj)
        assert out.shape == y.shape and out.dtype == y.dtype
    torch.testing.assert_close(RLSPredictor().predict(traj)[:, 1], y[:, 0])  # copies before p samples
