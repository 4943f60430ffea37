"""EKF, UKF and particle filter: on a linear-Gaussian system they must match the Kalman filter (filterpy)."""

import dataclasses

import numpy as np
import pytest
import torch

from mop.config import SystemConfig
from mop.filters.ekf import EKFPredictor, ekf_predict
from mop.filters.particle import ParticleFilterPredictor
from mop.filters.ukf import UKFPredictor
from mop.predictors import Predictor, forecast, make_predictor
from mop.systems import generator, make_family, quadrotor
from tests.reference import filterpy_on, linear_traj, monte_carlo_bias, quad_traj


def test_ekf_on_linear_system_equals_kalman_filter():
    traj = linear_traj()
    yhat = EKFPredictor().predict(traj).numpy()
    np.testing.assert_allclose(yhat, filterpy_on(traj), atol=1e-9)


def test_ukf_on_linear_system_equals_kalman_filter():
    traj = linear_traj(seed=1)
    for predictor in (UKFPredictor(), UKFPredictor(alpha=0.5, beta=2.0, kappa=1.0)):
        yhat = predictor.predict(traj).numpy()
        np.testing.assert_allclose(yhat, filterpy_on(traj), atol=1e-8)


def scalar_traj(num_systems: int, horizon: int, seed: int, **kw):
    """Seeded scalar linear systems (n = m = 1) in float64: many independent systems, few particles needed."""
    config = SystemConfig(family="linear", state_dim=1, output_dim=1, noise_var_w=0.1, noise_var_v=0.1, **kw)
    return make_family(config, torch.float64).generate(num_systems, horizon, generator=generator(seed))


def test_particle_filter_is_the_kalman_filter_within_its_monte_carlo_error():
    """On linear-Gaussian systems the PF's predictions and k-step forecasts converge to the KF's (the exact
    answer): two runs with independent draws (seeds 0, 1), each minus the KF, have a mean cross product
    (the squared bias) within 3 standard errors of 0 over 120 systems. A 10% error in the process noise's
    std or in R^-1 makes it 5 to 20 standard errors."""
    traj = scalar_traj(120, 15, seed=2)
    kf = forecast(make_predictor("kalman"), traj, 3).numpy()
    a, b = (forecast(ParticleFilterPredictor(4000, seed=s), traj, 3).numpy() - kf for s in (0, 1))
    keep = ~np.isnan(kf[0])  # the entries inside the horizon
    bias2, se = monte_carlo_bias(a[:, keep], b[:, keep])
    assert bias2 < 3 * se, (bias2, se)
    assert np.mean(a[:, keep] ** 2) < 1e-3 * np.mean((traj.y.numpy() - kf[:, :, 0]) ** 2)  # and small


def test_particle_filter_is_seeded():
    traj = linear_traj(num_systems=2, horizon=5)
    a, b = (ParticleFilterPredictor(200, seed=3).predict(traj) for _ in range(2))
    c = ParticleFilterPredictor(200, seed=4).predict(traj)
    assert torch.equal(a, b) and not torch.equal(a, c)


def test_quadrotor_filters_run_and_beat_the_prior():
    traj = make_family(SystemConfig(family="quadrotor"), torch.float64).generate(
        50, 30, generator=generator(4)
    )
    prior_err = (traj.y - traj.y.mean()).norm(dim=-1)[:, 5:].mean()
    C, P0 = traj.params.C, traj.params.P0
    prior_mean = (C @ traj.params.x0_mean[..., None])[..., 0]  # (B, m), yhat_0 uses no data
    pf_sd = (
        torch.diagonal(C @ P0 @ C.mT, dim1=-2, dim2=-1).sqrt() / 300**0.5
    )  # Monte Carlo sd of the PF's mean
    for predictor, tol in (
        (EKFPredictor(), 1e-12),
        (UKFPredictor(), 1e-12),
        (ParticleFilterPredictor(300), 5 * pf_sd),
    ):
        assert isinstance(predictor, Predictor)
        yhat = predictor.predict(traj)
        assert yhat.shape == traj.y.shape and yhat.dtype == traj.y.dtype and torch.isfinite(yhat).all()
        assert ((yhat[:, 0] - prior_mean).abs() <= tol).all()
        assert (yhat - traj.y).norm(dim=-1)[:, 5:].mean() < prior_err


def test_ekf_step_clips_like_the_authors_ekf():
    """One EKF step from a known state m_0 outside the bounds (P0 ~ 0, so the posterior mean is m_0):
    ekf: yhat_0 = C clip(m_0), yhat_1 = C clip(f(clip(m_0), u_0));
    ekf-noclip: yhat_0 = C m_0, yhat_1 = C f(m_0, u_0)."""
    traj = quad_traj(5, 2, 5)
    p = dataclasses.replace(
        traj.params,
        P0=traj.params.P0 * 0 + 1e-12 * torch.eye(6, dtype=torch.float64),  # x_0 known = x0_mean
        x0_mean=torch.tensor([[25.0, -1.0, 1.2, 0.5, -2.5, 1.0]], dtype=torch.float64).expand(5, 6),
    )
    f = lambda x: quadrotor.dynamics(x, traj.u[:, 0], p.mass, p.length, p.inertia)  # noqa: E731
    C = lambda x: (p.C @ x[..., None])[..., 0]  # noqa: E731
    clip = quadrotor.clip_state
    m0 = p.x0_mean
    model = quadrotor.QuadrotorFamily.state_space(p)
    yhat = ekf_predict(model, traj.y, traj.u)
    torch.testing.assert_close(yhat[:, 0], C(clip(m0)))
    torch.testing.assert_close(yhat[:, 1], C(clip(f(clip(m0)))), atol=1e-8, rtol=0)
    yhat = ekf_predict(model, traj.y, traj.u, project=False)
    torch.testing.assert_close(yhat[:, 0], C(m0))
    torch.testing.assert_close(yhat[:, 1], C(f(m0)), atol=1e-8, rtol=0)


def test_ekf_time_update_clips_the_posterior_mean_before_the_step():
    """The authors' EKF: m <- clip(f(clip(m), u)), P <- F P F^T + Q with F at the UNclipped posterior m."""
    from mop.filters.gaussian import ekf_step

    traj = quad_traj(4, 2, 10)
    model = quadrotor.QuadrotorFamily.state_space(traj.params)
    m = torch.tensor([[1.0, -25.0, -1.3, 2.4, -2.6, 0.9]], dtype=torch.float64).expand(4, 6)  # out of bounds
    P, Q, u = traj.params.P0, traj.params.Q, traj.u[:, 0]
    F = model.jacobian(m, u, 0)
    f = lambda x: model.f(x[:, None], u[:, None], 0)[:, 0]  # noqa: E731
    m_next, P_next = ekf_step(model, m, P, u, 0, quadrotor.clip_state)
    torch.testing.assert_close(m_next, quadrotor.clip_state(f(quadrotor.clip_state(m))))
    torch.testing.assert_close(P_next, F @ P @ F.mT + Q)
    m_next, P_next = ekf_step(model, m, P, u, 0, None)
    torch.testing.assert_close(m_next, f(m))


def test_projection_changes_nothing_where_it_never_binds(monkeypatch):
    """Linear families have no projection; on the quadrotor with huge bounds the clip is the identity.
    Either way the clipping filters equal the plain ones (the PF draw for draw, same seed)."""
    lin = linear_traj(num_systems=3, horizon=10, seed=8)
    traj = quad_traj(10, 30, 9)
    for data in (lin, "huge bounds"):
        if data == "huge bounds":
            monkeypatch.setattr(quadrotor, "BOUNDS", (1e9,) * 6)
            data = traj
        pf = lambda project: ParticleFilterPredictor(50, project=project)  # noqa: E731
        for make in (EKFPredictor, UKFPredictor, pf):
            torch.testing.assert_close(make(project=True).predict(data), make(project=False).predict(data))
    monkeypatch.undo()
    assert not torch.allclose(EKFPredictor().predict(traj), EKFPredictor(project=False).predict(traj))


def test_quadrotor_error_levels():
    """200 seeded systems, mean over systems of ||yhat_t - y_t|| over t in [20, 50). mop's EKF scores 0.58 on
    1000 systems (target 0.55-0.70, the authors' EKF 0.67-0.69 on their generator); 200-system means vary by
    ~0.03 across seeds, hence [0.52, 0.70]. Clipping must help every filter by a wide margin."""
    traj = quad_traj(200, 50, 12)
    err = lambda p: (p.predict(traj) - traj.y).norm(dim=-1)[:, 20:50].mean().item()  # noqa: E731
    ekf, ekf_noclip = err(EKFPredictor()), err(EKFPredictor(project=False))
    assert 0.52 < ekf < 0.70 and ekf < ekf_noclip - 0.3, (ekf, ekf_noclip)
    assert err(UKFPredictor()) < err(UKFPredictor(project=False)) - 0.3
    few = traj.select(slice(0, 40))
    err = lambda p: (p.predict(few) - few.y).norm(dim=-1)[:, 20:50].mean().item()  # noqa: E731
    assert err(ParticleFilterPredictor(100)) < 0.7 < 5 < err(ParticleFilterPredictor(100, project=False))


def test_unscented_time_update_closed_form():
    """f(x) = x^2 for x ~ N(mu, s^2): E f = mu^2 + s^2, Var f = 2 s^4 + 4 mu^2 s^2; the UT with n = 1,
    alpha = 1, beta = 0, kappa = 2 (points mu, mu +- sqrt(3) s) reproduces both exactly."""
    from mop.filters.gaussian import ukf_step_with
    from mop.systems.base import StateSpace

    mu, s2, q = torch.tensor([[0.7], [-1.3]], dtype=torch.float64), torch.tensor([0.2, 0.5]), 0.03
    P = s2.double()[:, None, None]  # (B, 1, 1)
    Q = torch.full((2, 1, 1), q, dtype=torch.float64)
    model = StateSpace(f=lambda x, u, t: x**2, C=torch.ones(2, 1, 1), Q=Q, R=Q, m0=mu, P0=P)
    m, P_next = ukf_step_with(alpha=1.0, beta=0.0, kappa=2.0)(model, mu, P, None, 0)
    mu, s2 = mu[:, 0], s2.double()
    torch.testing.assert_close(m[:, 0], mu**2 + s2)
    torch.testing.assert_close(P_next[:, 0, 0], 2 * s2**2 + 4 * mu**2 * s2 + q)


def test_covariance_factor_is_cholesky_where_it_can_be_and_jitters_only_the_systems_that_fail():
    """A noise-free system's covariance collapses onto a subspace and rounding can leave it indefinite (the
    UKF on wiener-hammerstein records raised from torch.linalg.cholesky): such a P is factored with the
    smallest jitter that works, L L^T = P to 1e-12 of its scale; every positive definite P in the same
    batch keeps torch's Cholesky factor bit for bit."""
    from mop.filters.gaussian import covariance_factor

    g = torch.Generator().manual_seed(0)
    A = torch.randn(3, 5, 5, dtype=torch.float64, generator=g)
    P = A @ A.mT + 0.1 * torch.eye(5, dtype=torch.float64)  # positive definite
    a = torch.randn(5, 2, dtype=torch.float64, generator=g)
    P[1] = a @ a.T - 1e-16 * torch.eye(5, dtype=torch.float64)  # rank 2, made indefinite by "rounding"
    with pytest.raises(torch.linalg.LinAlgError):
        torch.linalg.cholesky(P[1])
    L = covariance_factor(P)
    for i in (0, 2):
        assert torch.equal(L[i], torch.linalg.cholesky(P[i]))
    assert torch.equal(L[1], L[1].tril())
    torch.testing.assert_close(L[1] @ L[1].T, P[1], rtol=0, atol=1e-12 * float(P[1].diagonal().mean()))
