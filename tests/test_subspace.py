"""Subspace identification: Hankel layout, Markov parameters of a known system, causality, fallback."""

import numpy as np
import torch

from mop.filters.rls import rls_predict
from mop.filters.subspace import N4SIDKalmanPredictor, block_hankel, identify, n4sid_kalman_predict
from mop.systems.base import Trajectories


def test_block_hankel_layout():
    y = torch.randn(2, 9, 3, generator=torch.Generator().manual_seed(0))
    H = block_hankel(y, 4).numpy()
    for b in range(2):
        ref = np.stack([np.concatenate([y[b, k + c].numpy() for k in range(4)]) for c in range(6)], axis=1)
        np.testing.assert_array_equal(H[b], ref)
    assert H.shape == (2, 12, 6)


def innovation_system(num_steps, generator):
    """x_{t+1} = A x_t + K e_t, y_t = C x_t + e_t with unit-variance white e (3 independent runs)."""
    A = torch.tensor([[0.8, 0.3], [-0.2, 0.5]], dtype=torch.float64)
    C = torch.tensor([[1.0, 0.5], [0.2, -1.0]], dtype=torch.float64)
    K = torch.tensor([[0.5, 0.1], [0.0, 0.3]], dtype=torch.float64)
    e = torch.randn(3, num_steps, 2, generator=generator, dtype=torch.float64)
    x, ys = torch.zeros(3, 2, dtype=torch.float64), []
    for t in range(num_steps):
        ys.append(x @ C.T + e[:, t])
        x = x @ A.T + e[:, t] @ K.T
    return A, C, K, torch.stack(ys, dim=1)


def test_recovers_markov_parameters():
    """C A^k K is invariant to the state basis; from 4000 samples the estimate is within 0.05 of the truth
    (its sampling error is about 1/sqrt(4000) ~ 0.016 per entry, plus a small bias from the finite past)."""
    A, C, K, y = innovation_system(4000, torch.Generator().manual_seed(0))
    Ah, Ch, Kh = identify(y, order=2, num_block_rows=8)
    for k in range(5):
        true = C @ torch.linalg.matrix_power(A, k) @ K
        est = Ch @ torch.linalg.matrix_power(Ah, k) @ Kh  # (3, 2, 2)
        torch.testing.assert_close(est, true.expand_as(est), atol=0.05, rtol=0)
    eig_true = np.sort_complex(np.linalg.eigvals(A.numpy()))
    for b in range(3):
        np.testing.assert_allclose(np.sort_complex(np.linalg.eigvals(Ah[b].numpy())), eig_true, atol=0.05)


def test_prediction_is_causal_and_falls_back_to_rls():
    _, _, _, y = innovation_system(40, torch.Generator().manual_seed(1))
    yhat = n4sid_kalman_predict(y, order=2, min_prefix=15)
    torch.testing.assert_close(yhat[:, :15], rls_predict(y, 2)[:, :15])
    t0 = 25
    changed = y.clone()
    changed[:, t0:] += 10.0
    torch.testing.assert_close(
        n4sid_kalman_predict(changed, order=2, min_prefix=15)[:, : t0 + 1], yhat[:, : t0 + 1]
    )


def test_identified_predictor_beats_rls_on_long_data():
    """On 300 steps of an ARMA-type innovation model, the identified Kalman predictor's error over the last
    100 steps is below that of RLS-AR(2), which cannot represent the MA part exactly."""
    A, C, K, y = innovation_system(300, torch.Generator().manual_seed(2))
    traj = Trajectories(y=y)
    model = N4SIDKalmanPredictor(order=2, min_prefix=200, every=20).predict(traj)
    err = lambda yh: ((yh - y)[:, 200:] ** 2).mean()  # noqa: E731
    assert err(model) < err(rls_predict(y, 2))
