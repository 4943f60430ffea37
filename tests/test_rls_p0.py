"""model.rls_p0 and priors across gaps: the RLS / ARX recursion from P_0 = p0 I is the ridge solution with
weight 1 / p0 (numpy), a large p0 identifies a noise-free ARX system exactly where the paper's P_0 = I
leaves a bias, and the gap recursion started from a prior equals the complete-data one where nothing is
missing and the fixed ARX's simulation across a gap where the prior is tight."""

import numpy as np
import pytest
import torch

from mop.errors import MopError
from mop.filters.arx import arx_predict, arx_regressors
from mop.filters.rls import _rls_run_gaps, rls_loop
from mop.models import build_model
from tests.test_feature_prior import tiny

TRUE = np.array([1.5, -0.7, 1.0, 0.5])  # y_{t+1} = 1.5 y_t - 0.7 y_{t-1} + u_t + 0.5 u_{t-1}


def noise_free(T: int = 60, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    rng = np.random.default_rng(seed)
    u, y = rng.normal(size=T), np.zeros(T)
    y[0], y[1] = rng.normal(size=2)
    for t in range(1, T - 1):
        y[t + 1] = TRUE @ [y[t], y[t - 1], u[t], u[t - 1]]
    return torch.tensor(y)[None, :, None], torch.tensor(u)[None, :, None]


@pytest.mark.parametrize("p0", [1.0, 1e4])
def test_the_recursion_from_p0_is_the_ridge_solution(p0):
    y, u = noise_free(T=30)
    pred = arx_predict(y, u, 2, 2, prior=(torch.zeros(4, 1, dtype=torch.float64), p0))[0, -1, 0].item()
    yn, un = y[0, :, 0].numpy(), u[0, :, 0].numpy()
    X = np.stack([yn[1:-2], yn[:-3], un[1:-2], un[:-3]], axis=1)  # the pairs up to y_{T-2}
    theta = np.linalg.solve(np.eye(4) / p0 + X.T @ X, X.T @ yn[2:-1])
    assert pred == pytest.approx(np.array([yn[-2], yn[-3], un[-2], un[-3]]) @ theta, rel=1e-8)


def test_a_weak_ridge_identifies_a_noise_free_system_exactly():
    """After 20 pairs the noise-free ARX(2, 2) system is predicted to 1e-6 with p0 = 1e8 (least squares);
    P_0 = I (the ridge 1 towards 0) leaves an error above 1e-4."""
    y, u = noise_free()
    zero = torch.zeros(4, 1, dtype=torch.float64)
    weak = arx_predict(y, u, 2, 2, prior=(zero, 1e8))[0, 25:, 0]
    paper = arx_predict(y, u, 2, 2)[0, 25:, 0]
    target = y[0, 25:, 0]
    assert (weak - target).abs().max() < 1e-6 * target.abs().max()
    assert (paper - target).abs().max() > 1e-4 * target.abs().max()


def test_gap_recursion_with_a_prior_equals_the_complete_one_and_simulates_a_tight_prior():
    y, u = noise_free(T=40, seed=1)
    prior = (torch.tensor([[1.2], [-0.5], [0.8], [0.3]], dtype=torch.float64), 0.3)
    phi = arx_regressors(y, u, 2, 2)
    complete = rls_loop(y, phi, 2, prior)[0]
    gapped = _rls_run_gaps(y, 2, extra=arx_regressors(y, u, 2, 2)[..., 2:], start=2, prior=prior)[0]
    torch.testing.assert_close(gapped, complete, rtol=1e-10, atol=1e-10)
    # a tight prior (P_0 -> 0) never moves: across a gap y_20..y_29 the prediction is the fixed ARX's
    # simulation from the filled outputs
    tight = (prior[0], 1e-14)
    holed = y.clone()
    holed[:, 20:30] = float("nan")
    got = arx_predict(holed, u, 2, 2, prior=tight)[0, :, 0].numpy()
    theta, yn, un = prior[0][:, 0].numpy(), y[0, :, 0].numpy(), u[0, :, 0].numpy()
    filled = yn.copy()
    for t in range(20, 30):
        filled[t] = theta @ [filled[t - 1], filled[t - 2], un[t - 1], un[t - 2]]
    np.testing.assert_allclose(got[20:30], filled[20:30], rtol=1e-9, atol=1e-9)


def test_rls_p0_errors():
    with pytest.raises(MopError, match="model.rls_p0 must be > 0"):
        tiny(rls_p0=0.0)
    with pytest.raises(MopError, match="without a listed model.rls_prior"):
        build_model(tiny(rls_prior=[0.9, -0.2, 0.5, 0.1, 0.05], rls_p0=10.0))
