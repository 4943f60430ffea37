"""Missing outputs in the identifiers: RLS skips the pairs with a missing target or regressor and fills the
missing regressors with its own predictions (against batch ridge regression); N4SID refuses gaps."""

import dataclasses

import numpy as np
import pytest
import torch

from mop.errors import MopError
from mop.filters.rls import _rls_run, _rls_run_gaps, regressors, rls_forecast, rls_predict
from mop.predictors import make_predictor
from tests.reference import linear_traj, rls_gaps_reference
from tests.test_missing_filters import with_gaps


def test_rls_gap_path_without_gaps_is_the_plain_rls_bit_for_bit():
    y = linear_traj(num_systems=5, horizon=30).y
    for order in (1, 2, 3):
        plain, gaps = _rls_run(y, order), _rls_run_gaps(y, order)
        assert torch.equal(plain[0], gaps[0]) and torch.equal(plain[1], gaps[1])


@pytest.mark.parametrize("order", [1, 2])
def test_rls_with_gaps_equals_batch_ridge_on_the_complete_pairs(order):
    traj = with_gaps(linear_traj(num_systems=3, horizon=25, seed=3), rate=0.25, whole_steps=(9, 10))
    yhat = rls_predict(traj.y, order).numpy()
    for b in range(3):
        ref = rls_gaps_reference(traj.y[b].numpy(), order)
        np.testing.assert_allclose(yhat[b], ref, atol=1e-9, rtol=0)


@pytest.mark.parametrize("p,q", [(2, 2), (1, 3)])
def test_gap_path_with_input_regressors_equals_batch_ridge(p, q):
    traj = with_gaps(linear_traj(num_systems=2, horizon=20, seed=4), rate=0.25)
    u = torch.randn(2, 21, 1, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    yhat = _rls_run_gaps(traj.y, p, extra=regressors(u, q), start=max(p, q))[0].numpy()
    for b in range(2):
        ref = rls_gaps_reference(traj.y[b].numpy(), p, u[b].numpy(), q)
        np.testing.assert_allclose(yhat[b], ref, atol=1e-9, rtol=0)


def test_rls_forecast_and_rls_best_run_with_gaps():
    traj = with_gaps(linear_traj(num_systems=3, horizon=20), rate=0.3)
    fc = rls_forecast(traj.y, 2, 4)
    assert torch.equal(fc[:, :, 0], rls_predict(traj.y, 2)) and torch.isfinite(fc[:, :-4]).all()
    assert torch.isfinite(make_predictor("rls-best").predict(traj)).all()


def test_last_value_carries_the_last_measured_value_forward():
    traj = with_gaps(linear_traj(num_systems=2, horizon=10), rate=0.3, whole_steps=(3, 4))
    yhat = make_predictor("last").predict(traj).numpy()
    y = traj.y.numpy()
    for b in range(2):
        for i in range(y.shape[2]):
            last = 0.0
            for t in range(y.shape[1]):
                assert yhat[b, t, i] == last
                last = last if np.isnan(y[b, t, i]) else y[b, t, i]


def test_n4sid_refuses_gaps_in_one_line():
    traj = with_gaps(linear_traj(num_systems=2, horizon=30), rate=0.1)
    with pytest.raises(MopError, match="n4sid") as err:
        make_predictor("n4sid-kf").predict(traj)
    assert "\n" not in str(err.value)


def test_arx_with_gaps_and_inputs_equals_batch_ridge_on_the_complete_pairs():
    """The registered `arx` (p = q = 2) skips pairs with a missing target or output regressor; its input
    lags are complete regressors (the same reference as the gap path above, through the predictor)."""
    traj = with_gaps(linear_traj(num_systems=2, horizon=20, seed=5), rate=0.25)
    u = torch.randn(2, 21, 1, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    traj = dataclasses.replace(traj, u=u)
    yhat = make_predictor("arx").predict(traj).numpy()
    for b in range(2):
        ref = rls_gaps_reference(traj.y[b].numpy(), 2, u[b].numpy(), 2)
        np.testing.assert_allclose(yhat[b], ref, atol=1e-9, rtol=0)
    assert torch.isfinite(make_predictor("arx-best").predict(traj)).all()


def test_gap_path_with_simulated_tails_and_drop_outs_equals_batch_ridge():
    """The class models' case: each system's outputs missing from a step of its own to the end (a simulated
    tail: no fit after it, the regressors all filled in), drop-outs before it, two channels, inputs."""
    traj = with_gaps(linear_traj(num_systems=3, horizon=40, seed=5), rate=0.15)
    y = traj.y.clone()
    m = y.shape[2]
    y = y[..., :2] if m > 2 else y
    for b, cut in enumerate((18, 27, 41)):  # the last system has no tail
        y[b, cut:] = float("nan")
    u = torch.randn(3, 41, 1, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    yhat = _rls_run_gaps(y, 3, extra=regressors(u, 2), start=3)[0].numpy()
    for b in range(3):
        ref = rls_gaps_reference(y[b].numpy(), 3, u[b].numpy(), 2)
        np.testing.assert_allclose(yhat[b], ref, atol=1e-9, rtol=0)
