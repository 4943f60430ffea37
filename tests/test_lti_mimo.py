"""The lti-mimo family: lti-siso's class with k inputs and m outputs (mop.systems.lti_mimo)."""

import numpy as np
import pytest
import torch

from mop.config import SystemConfig
from mop.errors import MopError
from mop.predictors import make_predictor
from mop.systems import generator, make_family
from mop.systems.lti_siso import lsim, sample_drss


def test_one_input_one_output_draws_exactly_lti_siso():
    siso = make_family(SystemConfig(family="lti-siso"), torch.float64).generate(8, 60, generator=generator(5))
    mimo = make_family(SystemConfig(family="lti-mimo", num_inputs=1, num_outputs=1), torch.float64).generate(
        8, 60, generator=generator(5)
    )
    assert torch.equal(siso.y, mimo.y) and torch.equal(siso.u, mimo.u)
    assert torch.equal(siso.params.C, mimo.params.C) and torch.equal(siso.params.B, mimo.params.B)


def test_every_input_moves_the_state_and_every_output_reads_it():
    """Each input's column of B and each output's row of C has a kept entry in the used states, about 80%
    of the used entries are kept (lti-siso's mask rate), and the padding stays zero."""
    d = sample_drss(3000, 10, True, generator(0), num_inputs=2, num_outputs=3)
    used = torch.arange(10)[None] < d.order[:, None]  # (B, n)
    assert (d.C.abs().sum(-1) > 0).all() and (d.B.abs().sum(-2) > 0).all()
    assert d.C[~used[:, None, :].expand_as(d.C)].abs().sum() == 0
    kept = (d.C != 0)[used[:, None, :].expand_as(d.C)].double().mean()
    assert 0.77 < float(kept) < 0.84  # 0.8, a little above for the rows redrawn when all were masked


def test_outputs_are_normalized_each_and_the_filter_that_knows_the_system_is_exact():
    """Every output channel of every trajectory has mean 0 and std 1 over time (its normalization), and the
    Kalman filter on the family's state space predicts the noise-free outputs exactly (x_0 = 0 is known and
    the system noise-free: zero error from t = 0, up to the jitter), also against the plain simulation."""
    traj = make_family(SystemConfig(family="lti-mimo"), torch.float64).generate(
        20, 99, generator=generator(2)
    )
    y = traj.y.numpy()
    assert y.shape == (20, 100, 3) and traj.u.shape == (20, 100, 1)
    np.testing.assert_allclose(y.mean(axis=1), 0.0, atol=1e-9)
    std = y.std(axis=1)
    constant = traj.params.y_std.numpy() < 1e-8  # an output that never moves stays 0
    np.testing.assert_allclose(std[~constant], 1.0, atol=1e-4)
    p = traj.params
    _, y_raw = lsim(p.A, p.B, p.C, torch.zeros(20, 3, 1, dtype=torch.float64), traj.u)
    expected = (y_raw - p.y_mean[:, None]) / (p.y_std[:, None] + 1e-6)
    np.testing.assert_allclose(y, expected, atol=1e-9)
    yhat = make_predictor("kalman").predict(traj).numpy()  # yhat[:, t] predicts y[:, t] from y[:, :t]
    assert np.abs(yhat - y).max() < 1e-6


@pytest.mark.parametrize("key, value", [("num_outputs", 0), ("num_inputs", 1.5), ("num_outputs", True)])
def test_a_width_that_is_not_a_positive_integer_is_refused_in_one_line(key, value):
    with pytest.raises(MopError, match=f"system.{key} must be a positive integer"):
        SystemConfig(family="lti-mimo", **{key: value})
