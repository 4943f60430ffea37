"""The Kalman filter with inputs (x_{t+1} = A x_t + B u_t + w_t): against filterpy's KalmanFilter with B and
u, against brute-force Gaussian conditioning on a short trajectory's joint covariance, and equal to the EKF
on every linear family with inputs."""

import numpy as np
import pytest
import torch

from mop.config import SystemConfig
from mop.errors import MopError
from mop.filters.gaussian import gaussian_filter, kalman_step
from mop.filters.kalman import kalman_filter, kalman_predict
from mop.plugins import MODULE_PREFIX
from mop.predictors import forecast, make_predictor
from mop.systems import FAMILIES, generator, make_family, state_space_of
from tests.reference import filterpy_forecast, filterpy_predict, gaussian_conditioning_predict
from tests.test_kalman import random_spd, random_system


def input_system(rng, B, n, m, k, T):
    A, C, Q, R = random_system(rng, B, n, m)
    Bm, u = rng.normal(size=(B, n, k)), rng.normal(size=(B, T, k))
    x0, P0 = rng.normal(size=(B, n)), random_spd(rng, B, n, scale=1.0)
    x = x0 + np.einsum("bij,bj->bi", np.linalg.cholesky(P0), rng.normal(size=(B, n)))
    Lq, Lr, ys = np.linalg.cholesky(Q), np.linalg.cholesky(R), []
    for t in range(T):
        ys.append(np.einsum("bij,bj->bi", C, x) + np.einsum("bij,bj->bi", Lr, rng.normal(size=(B, m))))
        x = np.einsum("bij,bj->bi", A, x) + np.einsum("bij,bj->bi", Bm, u[:, t])
        x = x + np.einsum("bij,bj->bi", Lq, rng.normal(size=(B, n)))
    return A, C, Q, R, np.stack(ys, axis=1), x0, P0, Bm, u


@pytest.mark.parametrize("n,m,k", [(1, 1, 1), (3, 2, 1), (5, 3, 3), (7, 1, 2)])
def test_kalman_with_inputs_matches_filterpy(n, m, k):
    """Odd dimensions, full (non-diagonal) Q and R, random x0 and P0: relative 1e-10."""
    rng = np.random.default_rng(100 * n + 10 * m + k)
    A, C, Q, R, y, x0, P0, B, u = input_system(rng, 3, n, m, k, 25)
    ref = filterpy_predict(A, C, Q, R, y, x0, P0, B, u)
    yhat = kalman_predict(A, C, Q, R, y, x0, P0, B, u)
    np.testing.assert_allclose(yhat, ref, rtol=1e-10, atol=1e-10 * np.abs(ref).max())
    without = filterpy_predict(A, C, Q, R, y, x0, P0)  # the inputs matter: dropping B u is far off
    assert np.abs(without - ref).max() > 1e-2


def test_kalman_with_inputs_is_the_gaussian_conditional_mean():
    rng = np.random.default_rng(7)
    A, C, Q, R, y, x0, P0, B, u = input_system(rng, 2, 3, 2, 2, 8)
    yhat = kalman_predict(A, C, Q, R, y, x0, P0, B, u)
    for b in range(2):
        ref = gaussian_conditioning_predict(A[b], C[b], Q[b], R[b], y[b], x0[b], P0[b], B[b], u[b])
        np.testing.assert_allclose(yhat[b], ref, rtol=1e-9, atol=1e-9)


def test_kalman_filter_needs_both_b_and_u():
    rng = np.random.default_rng(0)
    A, C, Q, R, y, x0, P0, B, u = input_system(rng, 1, 2, 1, 1, 5)
    with pytest.raises(MopError, match="both the input matrix B and the inputs u"):
        kalman_filter(A, C, Q, R, y, x0, P0, B=B)


def linear_input_families() -> list[str]:
    """mop's own registered families with inputs whose systems have a linear (A, B, C) description (not the
    examples' plugins, which other tests in the same process may have imported)."""
    out = []
    for name in FAMILIES.names():
        family = make_family(SystemConfig(family=name))
        if type(family).__module__.startswith(MODULE_PREFIX):
            continue
        if family.input_dim > 0 and {"A", "B", "C"} <= set(family.Params.names()):
            out.append(name)
    return out


def test_there_is_a_linear_family_with_inputs():
    assert "linear-inputs" in linear_input_families()


def linear_inputs_matrices(traj):
    """linear-inputs: x' = A x + B u + w, y = C x + v, x_0 ~ N(0, P0), from the sampled params."""
    p = traj.params.map(torch.Tensor.numpy)
    return p.A, p.B, p.C, p.Q, p.R, np.zeros(p.A.shape[:2]), p.P0


def lti_siso_matrices(traj):
    """lti-siso (its state_space docstring): the normalized output of [x; 1], A_aug = blockdiag(A, 1),
    B_aug = [B; 0], C_aug = [C, -mean] / (std + 1e-6), x_0 = [0; 1], Q = P0 = 1e-10 I,
    R = noise_std^2 + 1e-10."""
    p = traj.params.map(torch.Tensor.numpy)
    Bn, n = p.A.shape[:2]
    A = np.zeros((Bn, n + 1, n + 1))
    A[:, :n, :n], A[:, n, n] = p.A, 1.0
    B = np.concatenate([p.B, np.zeros((Bn, 1, p.B.shape[-1]))], axis=1)
    C = np.concatenate([p.C, -p.y_mean[:, None, None]], axis=-1) / (p.y_std + 1e-6)[:, None, None]
    Q = np.broadcast_to(1e-10 * np.eye(n + 1), (Bn, n + 1, n + 1)).copy()
    R = (p.noise_std**2 + 1e-10)[:, None, None]
    x0 = np.zeros((Bn, n + 1))
    x0[:, n] = 1.0
    return A, B, C, Q, R, x0, Q.copy()


def lti_mimo_matrices(traj):
    """lti-mimo (its state_space docstring): lti-siso's with each output row i of C_aug
    [C_i, -mean_i] / (std_i + 1e-6), R = (noise_std^2 + 1e-10) I_m."""
    p = traj.params.map(torch.Tensor.numpy)
    Bn, n = p.A.shape[:2]
    m = p.C.shape[1]
    A = np.zeros((Bn, n + 1, n + 1))
    A[:, :n, :n], A[:, n, n] = p.A, 1.0
    B = np.concatenate([p.B, np.zeros((Bn, 1, p.B.shape[-1]))], axis=1)
    C = np.concatenate([p.C, -p.y_mean[:, :, None]], axis=-1) / (p.y_std + 1e-6)[:, :, None]
    Q = np.broadcast_to(1e-10 * np.eye(n + 1), (Bn, n + 1, n + 1)).copy()
    R = (p.noise_std**2 + 1e-10)[:, None, None] * np.eye(m)
    x0 = np.zeros((Bn, n + 1))
    x0[:, n] = 1.0
    return A, B, C, Q, R, x0, Q.copy()


MATRICES = {
    "linear-inputs": linear_inputs_matrices,
    "lti-siso": lti_siso_matrices,
    "lti-mimo": lti_mimo_matrices,
}


def test_every_linear_family_with_inputs_has_its_reference_matrices():
    assert set(linear_input_families()) == set(MATRICES)


@pytest.mark.parametrize("family", sorted(MATRICES))
@pytest.mark.parametrize("name", ["kalman", "ekf"])
def test_kalman_and_ekf_with_inputs_match_filterpy(family, name):
    """The KF and the EKF on every linear family with inputs, against filterpy's KalmanFilter with B and u
    on the family's matrices built here from its params (not from mop's state-space function): one-step
    predictions and 4-step forecasts."""
    traj = make_family(SystemConfig(family=family), torch.float64).generate(4, 30, generator=generator(3))
    A, B, C, Q, R, x0, P0 = MATRICES[family](traj)
    y, u = traj.y.numpy(), traj.u.numpy()
    predictor = make_predictor(name)
    ref = filterpy_predict(A, C, Q, R, y, x0, P0, B, u)
    scale = np.abs(ref).max()
    np.testing.assert_allclose(predictor.predict(traj).numpy(), ref, rtol=1e-8, atol=1e-8 * scale)
    ref = filterpy_forecast(A, C, Q, R, y, x0, P0, 4, B, u)
    fc = forecast(predictor, traj, 4).numpy()
    np.testing.assert_allclose(fc, ref, rtol=1e-8, atol=1e-8 * scale, equal_nan=True)


def test_kalman_predictor_on_linear_inputs_matches_filterpy():
    traj = make_family(SystemConfig(family="linear-inputs"), torch.float64).generate(
        5, 30, generator=generator(1)
    )
    p = traj.params.map(torch.Tensor.numpy)
    y, u = traj.y.numpy(), traj.u.numpy()
    x0 = np.zeros((5, p.A.shape[-1]))
    ref = filterpy_predict(p.A, p.C, p.Q, p.R, y, x0, p.P0, p.B, u)
    np.testing.assert_allclose(make_predictor("kalman").predict(traj).numpy(), ref, rtol=1e-10, atol=1e-12)


def test_kalman_forecast_with_inputs_is_the_noise_free_rollout():
    """forecast[:, t, j] = C (A^j m_t + sum_i A^{j-1-i} B u_{t+i}): the mean rolled out with known inputs."""
    traj = make_family(SystemConfig(family="linear-inputs"), torch.float64).generate(
        3, 20, generator=generator(2)
    )
    kf = make_predictor("kalman")
    fc = forecast(kf, traj, 5)
    A, B, C = traj.params.A, traj.params.B, traj.params.C
    t = 6
    priors = {}
    gaussian_filter(
        state_space_of(traj),
        kalman_step,
        traj.y,
        traj.u,
        at_prior=lambda s, m, P, proj: priors.__setitem__(s, m.clone()),
    )
    m = priors[t]
    for j in range(5):
        np.testing.assert_allclose(fc[:, t, j], (C @ m[..., None])[..., 0], rtol=1e-10, atol=1e-12)
        m = (A @ m[..., None])[..., 0] + (B @ traj.u[:, t + j, :, None])[..., 0]
