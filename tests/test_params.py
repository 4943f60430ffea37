"""Typed system parameters (mop.systems.params): every family declares its type, predictors read fields, one
check names a missing field in one line, saved data round-trips, and a dict-style family is refused."""

import dataclasses
import types

import numpy as np
import pytest
import torch

from mop.cli import main
from mop.config import SystemConfig
from mop.errors import MopError
from mop.experiments.analyses import ANALYSES
from mop.io import read_system
from mop.predictors import make_predictor
from mop.systems import FAMILIES, SystemFamily, SystemParams, Trajectories, generator, register_family
from mop.systems.state_space import LinearModelParams
from tests.reference import filterpy_on, filterpy_predict, linear_traj, quad_traj


def _one_line_error(fn) -> str:
    with pytest.raises(MopError) as err:
        fn()
    text = str(err.value)
    assert "\n" not in text
    return text


@pytest.mark.parametrize(
    "name, family, missing",
    [
        ("kalman-colored", "quadrotor", "parameters A, noise_var_w, noise_var_v, color_window"),
        ("kalman-system1", "quadrotor", "parameter A"),
        ("kalman-system1", "wiener-hammerstein", "parameters A, C, Q, R"),
    ],
)
def test_a_predictor_names_the_fields_the_data_lacks_in_one_line(name, family, missing):
    traj = FAMILIES.get(family)(SystemConfig(family=family)).generate(2, 5, generator=generator(0))
    text = _one_line_error(lambda: make_predictor(name).predict(traj))
    assert f"{name} needs the system {missing}, missing from these trajectories" in text
    assert f"they carry {type(traj.params).__name__}: {', '.join(traj.params.present())})" in text


def test_an_optional_field_left_at_none_counts_as_missing():
    """A known linear model without P0 (None: the Kalman filter's default I) lacks it for kalman-system1."""
    traj = linear_traj(2, 5)
    p = traj.params
    model = LinearModelParams(A=p.A, C=p.C, Q=p.Q, R=p.R)
    text = _one_line_error(
        lambda: make_predictor("kalman-system1").predict(Trajectories(traj.y, params=model))
    )
    assert "kalman-system1 needs the system parameter P0, missing from these trajectories" in text


def test_an_analysis_names_the_field_it_needs():
    result = types.SimpleNamespace(traj=quad_traj(2, 5, 0), extras={})
    text = _one_line_error(lambda: ANALYSES.get("matrix_powers")(result, [], "ekf"))
    assert "the matrix_powers analysis needs the system parameter A, missing from" in text


def test_field_reading_kalman_system1_equals_filterpy_on_a_linear_family():
    """kalman-system1 reads params.A, .C, .Q, .R, .P0 itself; on systems that never switch it is the KF."""
    traj = linear_traj(num_systems=5, horizon=25, seed=3, noise_var_w=0.02, noise_var_v=0.05)  # Q != R
    yhat = make_predictor("kalman-system1").predict(traj).numpy()
    np.testing.assert_allclose(yhat, filterpy_on(traj), rtol=1e-6, atol=1e-9)


def test_kalman_on_family_less_typed_params_equals_filterpy_with_the_defaults():
    """Data without a family carrying LinearModelParams with P0 and x0_mean left out: P0 = I, x0 = 0."""
    traj = linear_traj(num_systems=4, horizon=20, seed=4)
    p = traj.params
    data = Trajectories(traj.y, params=LinearModelParams(A=p.A, C=p.C, Q=p.Q, R=p.R))
    yhat = make_predictor("kalman").predict(data).numpy()
    a = p.map(torch.Tensor.numpy)
    eye = np.broadcast_to(np.eye(4), (4, 4, 4))
    ref = filterpy_predict(a.A, a.C, a.Q, a.R, traj.y.numpy(), np.zeros((4, 4)), eye)
    np.testing.assert_allclose(yhat, ref, rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("family", sorted(FAMILIES.names()))
def test_every_family_declares_its_type_and_round_trips_through_an_npz(family, tmp_path):
    """generate -> to_numpy_dict -> np.savez -> io.read_system -> Params.from_arrays: equal fields."""
    fam = FAMILIES.get(family)(SystemConfig(family=family))
    traj = fam.generate(3, 6, generator=generator(1))
    assert type(traj.params) is fam.Params and set(traj.params.present()) == set(fam.Params.required())
    np.savez(tmp_path / "d.npz", **traj.to_numpy_dict())
    name, arrays = read_system(tmp_path / "d.npz", 3)
    back = FAMILIES.get(name).Params.from_arrays(arrays, by="the test", where="d.npz")
    for (k, a), (j, b) in zip(traj.params.as_dict().items(), back.as_dict().items(), strict=True):
        assert k == j and a.dtype == b.dtype and torch.equal(a, b), k


def test_predict_learns_the_fields_from_the_type_without_sampling(tmp_path, capsys, monkeypatch):
    """lti-siso's y_mean and y_std come from a simulation, not from sample: the old look-up (sampling one
    system) missed them. The family's type names them, and nothing is sampled."""
    assert (
        main(["simulate", "lti-siso", "--systems", "2", "--horizon", "8", "--out", str(tmp_path / "s.npz")])
        == 0
    )
    d = dict(np.load(tmp_path / "s.npz"))
    del d["param_y_mean"]
    np.savez(tmp_path / "bad.npz", **d)
    lti = FAMILIES.get("lti-siso")
    monkeypatch.setattr(lti, "sample", lambda *a, **k: pytest.fail("mop predict sampled a system"))
    assert main(["predict", "kalman", str(tmp_path / "s.npz"), "--out", str(tmp_path / "p.npz")]) == 0
    assert main(["predict", "ekf", str(tmp_path / "bad.npz")]) == 2
    err = capsys.readouterr().err.strip()
    assert "ekf needs param_y_mean in" in err and "\n" not in err


def test_a_dict_style_family_is_refused_in_one_line():
    class OldStyle(SystemFamily):
        def sample(self, num_systems, *, generator):
            return {"A": torch.zeros(num_systems, 1, 1)}

    text = _one_line_error(lambda: register_family("old-style-dict", SystemConfig)(OldStyle))
    assert "family 'old-style-dict' declares no parameter type: set `Params` on OldStyle" in text
    assert "old-style-dict" not in FAMILIES.names()
    text = _one_line_error(lambda: Trajectories(torch.zeros(1, 3, 1), params={"A": torch.zeros(1, 1, 1)}))
    assert "Trajectories.params must be the family's parameter type (a SystemParams), got dict" in text


def test_select_map_and_extend_keep_the_type_and_the_rows():
    @dataclasses.dataclass(frozen=True)
    class Two(SystemParams):
        a: torch.Tensor
        b: torch.Tensor

    @dataclasses.dataclass(frozen=True)
    class Three(Two):
        c: torch.Tensor

    p = Two(a=torch.arange(4.0), b=torch.arange(8).reshape(4, 2))
    rows = p.select(torch.tensor([3, 1]))
    assert type(rows) is Two and rows.a.tolist() == [3.0, 1.0] and rows.b.tolist() == [[6, 7], [2, 3]]
    assert p.map(lambda t: t * 2).b.tolist() == [[0, 2], [4, 6], [8, 10], [12, 14]]
    q = Three.extend(p, c=torch.ones(4))
    assert type(q) is Three and q.a is p.a and Three.required() == ("a", "b", "c")
