"""`mop predict kalman DATA.npz` for any known linear-Gaussian model (param_A, param_C, param_Q, param_R,
optional param_B, param_P0, param_x0_mean), with or without `family`: against filterpy; missing arrays
named."""

import numpy as np
import pytest

from mop.cli import main
from tests.reference import filterpy_predict
from tests.test_kalman_inputs import input_system


def _write(path, arrays):
    np.savez(path, **arrays)
    return str(path)


@pytest.fixture
def model():
    rng = np.random.default_rng(3)
    A, C, Q, R, y, x0, P0, B, u = input_system(rng, 4, 3, 2, 1, 30)
    return {"A": A, "C": C, "Q": Q, "R": R, "y": y, "x0": x0, "P0": P0, "B": B, "u": u}


def _arrays(mdl, keys, family=None):
    out = {"y": mdl["y"]}
    names = {"x0": "x0_mean"}
    for k in keys:
        if k == "u":
            out["u"] = mdl["u"]
        else:
            out[f"param_{names.get(k, k)}"] = mdl[k]
    if family:
        out["family"] = np.array(family)
    return out


@pytest.mark.parametrize("family", [None, "linear", "linear-inputs"])
def test_kalman_on_a_known_linear_model_with_inputs_equals_filterpy(model, tmp_path, family):
    """With family "linear" / "linear-inputs" the file lacks that generator's arrays (noise_var_w, ...):
    the model in the file is used."""
    path = _write(tmp_path / "m.npz", _arrays(model, ["A", "C", "Q", "R", "B", "u", "P0", "x0"], family))
    assert main(["predict", "kalman", path, "--out", str(tmp_path / "p.npz")]) == 0
    ref = filterpy_predict(*(model[k] for k in ("A", "C", "Q", "R", "y", "x0", "P0", "B", "u")))
    yhat = np.load(tmp_path / "p.npz")["yhat"]
    np.testing.assert_allclose(yhat, ref, rtol=1e-5, atol=1e-5 * np.abs(ref).max())


def test_kalman_on_a_known_linear_model_defaults_p0_identity_and_zero_mean(model, tmp_path):
    path = _write(tmp_path / "m.npz", _arrays(model, ["A", "C", "Q", "R"]))
    assert main(["predict", "kalman", path, "--out", str(tmp_path / "p.npz")]) == 0
    B, n = model["A"].shape[:2]
    ref = filterpy_predict(
        *(model[k] for k in "ACQR"), model["y"], np.zeros((B, n)), np.tile(np.eye(n), (B, 1, 1))
    )
    np.testing.assert_allclose(np.load(tmp_path / "p.npz")["yhat"], ref, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize(
    "keys, message",
    [
        (["A", "C", "R"], "param_Q"),
        (["C", "Q", "R", "B", "u"], "param_A"),
        (["A", "C", "Q", "R", "u"], "param_B"),
        (["A", "C", "Q", "R", "B"], "no inputs u"),
    ],
)
def test_a_missing_array_is_named_in_one_line(model, tmp_path, capsys, keys, message):
    path = _write(tmp_path / "m.npz", _arrays(model, keys))
    assert main(["predict", "kalman", path, "--out", str(tmp_path / "p.npz")]) != 0
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err and "Traceback" not in err
    assert not (tmp_path / "p.npz").exists()


def test_a_misshapen_array_is_named(model, tmp_path, capsys):
    arrays = _arrays(model, ["A", "C", "Q", "R"])
    arrays["param_Q"] = arrays["param_Q"][:, :2, :2]
    assert main(["predict", "kalman", _write(tmp_path / "m.npz", arrays)]) != 0
    assert "param_Q has shape" in capsys.readouterr().err
