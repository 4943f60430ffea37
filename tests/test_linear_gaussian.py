"""mop.filters.linear_gaussian against the Kalman filter of mop.filters.kalman (tested against filterpy)
and against the families' own matrices."""

import dataclasses
import math

import pytest
import torch

from mop.config import SystemConfig
from mop.errors import MopError
from mop.filters.kalman import kalman_filter
from mop.filters.linear_gaussian import family_systems, kalman_means, linear_systems, predictor_gains
from mop.systems import generator, make_family


def _family(name: str, **kw):
    return make_family(SystemConfig(family=name, **kw), dtype=torch.float64)


@pytest.mark.parametrize(
    ("name", "kw"),
    [("linear-inputs", {"state_dim": 3, "output_dim": 2, "input_dim": 2}), ("linear", {})],
)
def test_kalman_means_equal_the_joseph_form_filter(name, kw):
    family = _family(name, **kw)
    traj = family.generate(16, 30, generator=generator(5))
    systems = linear_systems(family.state_space(traj.params), family.input_dim)
    ref = kalman_filter(
        systems.A, systems.C, systems.Q, systems.R, traj.y, systems.m0, systems.P0, systems.B, traj.u
    )
    got = kalman_means(systems, traj.y, traj.u)
    torch.testing.assert_close(got, ref.yhat, rtol=1e-9, atol=1e-9)
    # the likelihood terms: S_t^{-1} and log det S_t of the same filter's predictive covariances
    _, S_inv, logdet = predictor_gains(systems, traj.horizon)
    eye = torch.eye(traj.output_dim, dtype=torch.float64)
    torch.testing.assert_close(S_inv @ ref.S, eye.expand_as(ref.S), rtol=1e-8, atol=1e-8)
    torch.testing.assert_close(logdet, torch.logdet(ref.S), rtol=1e-9, atol=1e-9)


def test_linear_systems_reads_the_family_matrices():
    family = _family("linear-inputs", state_dim=3, output_dim=2, input_dim=2)
    params = family.sample(8, generator=generator(1))
    systems = linear_systems(family.state_space(params), family.input_dim)
    torch.testing.assert_close(systems.A, params.A.double())
    torch.testing.assert_close(systems.B, params.B.double())
    torch.testing.assert_close(systems.C, params.C.double())


def test_linear_systems_refuses_a_nonlinear_family():
    family = _family("cascaded-tanks")
    params = family.sample(4, generator=generator(0))
    with pytest.raises(MopError, match="not linear|constant term"):
        linear_systems(family.state_space(params), family.input_dim)


def test_kalman_means_refuse_gaps():
    family = _family("linear")
    traj = family.generate(2, 10, generator=generator(0))
    y = traj.y.clone()
    y[0, 3] = math.nan
    with pytest.raises(MopError, match="gaps"):
        kalman_means(linear_systems(family.state_space(traj.params), 0), y, None)


def test_dynamics_that_change_in_time_are_refused():
    family = _family("linear")
    model = family.state_space(family.sample(3, generator=generator(0)))
    A2 = 0.5 * model.jacobian(None, None, 0)
    changing = dataclasses.replace(
        model, f=lambda x, u, t: x @ (A2 if t >= 4 else model.jacobian(x, u, 0)).mT
    )
    linear_systems(changing, 0, horizon=3)  # the same up to t = 3
    with pytest.raises(MopError, match="change in time"):
        linear_systems(changing, 0, horizon=10)


@pytest.mark.parametrize(
    ("name", "match"), [("colored-noise", "only approximates"), ("switching", "varies in time")]
)
def test_family_systems_refuses_inexact_or_switching_families(name, match):
    family = _family(name)
    with pytest.raises(MopError, match=match):
        family_systems(family, family.sample(2, generator=generator(0)), 50)
