"""The in-context system-identification families (Forgione et al.'s generator, batched): pole law,
normalization, the cascade, and the filters that know each system."""

import math

import numpy as np
import pytest
import torch

from mop.config import SystemConfig
from mop.predictors import make_predictor
from mop.systems import generator, make_family, state_space_of
from mop.systems.lti_siso import lsim, sample_drss


def test_drss_pole_law_and_masks():
    p = sample_drss(2000, 10, True, generator(0))
    order = p.order
    assert order.min() == 1 and order.max() == 10
    eig = torch.linalg.eigvals(p.A)
    for b in range(200):  # the eigenvalues of the used block obey the law; padding is zero
        k = int(order[b])
        used = torch.sort(eig[b].abs(), descending=True).values[:k]
        assert (used > 0.5 - 1e-9).all() and (used < 0.97 + 1e-9).all()
        angle = eig[b].angle().abs()
        assert (angle[eig[b].abs() > 1e-9] <= math.pi / 2 + 1e-9).all()
        assert p.B[b, k:].abs().sum() == 0 and p.C[b, :, k:].abs().sum() == 0
    # masks: about 80% of the used B, C entries are kept (their pBCmask)
    used = torch.arange(10)[None] < order[:, None]
    kept = (p.B[..., 0] != 0)[used].double().mean()
    assert 0.77 < float(kept) < 0.83
    assert (p.D == 0).all()
    d = sample_drss(4000, 3, False, generator(1)).D
    assert 0.12 < float((d != 0).double().mean()) < 0.18  # P(D != 0) = 0.5 * 0.3


def test_lti_siso_trajectories_are_normalized_and_the_kalman_filter_is_exact():
    traj = make_family(SystemConfig(family="lti-siso"), torch.float64).generate(
        20, 99, generator=generator(2)
    )
    np.testing.assert_allclose(traj.y.mean(1), 0, atol=1e-9)
    np.testing.assert_allclose(traj.y.std(1, correction=0), 1, atol=1e-4)
    p = traj.params
    x, y_raw = lsim(p.A, p.B, p.C, torch.zeros(20, 1, 1, dtype=torch.float64), traj.u)
    expected = (y_raw - p.y_mean[:, None, None]) / (p.y_std[:, None, None] + 1e-6)
    np.testing.assert_allclose(traj.y, expected, atol=1e-9)
    yhat = make_predictor("kalman").predict(traj)  # knows the noise-free system: exact from t = 0
    assert float((yhat - traj.y).abs().max()) < 1e-6


def test_wiener_hammerstein_state_space_reproduces_the_simulation():
    """f iterated on the true state s_t gives s_{t+1}, and C s_t = y_t (noise free)."""
    traj = make_family(SystemConfig(family="wiener-hammerstein"), torch.float64).generate(
        8, 60, generator=generator(3)
    )
    model = state_space_of(traj)
    s = traj.x  # (B, T+1, d)
    nxt = model.f(s[:, :-1].reshape(8 * 60, 1, -1).reshape(8, 60, -1), traj.u[:, :-1], 0)
    np.testing.assert_allclose(nxt, s[:, 1:], atol=1e-9)
    np.testing.assert_allclose((s @ model.C.mT), traj.y, atol=1e-9)


def test_wiener_hammerstein_jacobian_matches_autograd():
    traj = make_family(SystemConfig(family="wiener-hammerstein"), torch.float64).generate(
        4, 10, generator=generator(4)
    )
    model = state_space_of(traj)
    s, u = traj.x[:, 5], traj.u[:, 5]
    auto = torch.func.jacrev(lambda z: model.f(z[:, None], u[:, None], 0)[:, 0].sum(0))(s).permute(1, 0, 2)
    np.testing.assert_allclose(model.transition_jacobian(s, u, 0), auto, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("name, factor", [("ekf", 0.25), ("ukf", 0.01)])
def test_filters_that_know_the_wh_system_beat_last_by_far(name, factor):
    """After 20 steps; the EKF linearizes tanh around a wide prior, so its early transient is larger."""
    traj = make_family(SystemConfig(family="wiener-hammerstein"), torch.float64).generate(
        10, 80, generator=generator(5)
    )
    err = lambda p: float(((make_predictor(p).predict(traj) - traj.y) ** 2)[:, 20:].mean())  # noqa: E731
    assert err(name) < factor * err("last")
