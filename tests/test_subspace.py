"""Subspace identification: Hankel layout, Markov parameters of a known system, causality, fallback."""

import numpy as np
import torch

from mop.filters.kalman import steady_state_predict
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


def test_identified_predictor_is_near_optimal_on_long_data():
    """On 300 steps of the innovation model, the identified predictor (model only, no RLS selection) has,
    over the last 100 steps, a squared error within 12% of the true steady-state predictor's (whose error is
    the innovation e itself): the excess of a fitted model is about (#parameters = 20) / (N = 200); measured
    4-8% on seeds 2-4."""
    A, C, K, y = innovation_system(300, torch.Generator().manual_seed(2))
    model = N4SIDKalmanPredictor(order=2, min_prefix=200, every=20, select=False).predict(Trajectories(y=y))
    best = steady_state_predict(A.expand(3, 2, 2), C.expand(3, 2, 2), K.expand(3, 2, 2), y)
    err = lambda yh: ((yh - y)[:, 200:] ** 2).mean()  # noqa: E731
    assert err(model) < 1.12 * err(best), (err(model), err(best))


def test_first_identification_waits_for_enough_hankel_columns():
    """m = 2, order 2 -> i = 2 block rows, Hankel 2 i m = 8 rows: the first model is used at t = 2i - 1 + 8
    = 11 (with min_prefix 5), RLS before."""
    _, _, _, y = innovation_system(30, torch.Generator().manual_seed(3))
    rls = rls_predict(y, 2)
    only_model = n4sid_kalman_predict(y, order=2, min_prefix=5, select=False)
    torch.testing.assert_close(only_model[:, :11], rls[:, :11])
    assert (only_model[:, 11] - rls[:, 11]).abs().amax() > 1e-6


def test_selection_picks_model_or_rls_by_past_error():
    """select=True: at each t the prediction is the model's or RLS's, whichever had the lower summed squared
    out-of-sample error before t (RLS at the first model step, where neither has a history)."""
    _, _, _, y = innovation_system(60, torch.Generator().manual_seed(4))
    rls = rls_predict(y, 2)
    model = n4sid_kalman_predict(y, order=2, min_prefix=11, select=False)
    chosen = n4sid_kalman_predict(y, order=2, min_prefix=11, select=True)
    sq = lambda yh: ((yh - y) ** 2).sum(-1)  # noqa: E731
    past = torch.cumsum(sq(model) - sq(rls), dim=1) - (sq(model) - sq(rls))  # (3, T): sum over s < t
    for t in range(11, 60):
        ref = torch.where((past[:, t] < 0)[:, None], model[:, t], rls[:, t])
        torch.testing.assert_close(chosen[:, t], ref)
    torch.testing.assert_close(chosen[:, 11], rls[:, 11])
