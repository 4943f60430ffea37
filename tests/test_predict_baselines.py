"""`mop predict PREDICTOR DATA` with registered predictors (and --steps forecasts)."""

import csv
import types

import numpy as np
import pytest
import torch

from mop.cli import main
from mop.predictors import forecast, make_predictor
from mop.systems import FAMILIES
from mop.systems.base import Trajectories
from tests.reference import read_long_csv, write_long_csv


@pytest.mark.parametrize("name", ["rls", "rls-best", "last", "zero", "n4sid-kf"])
def test_baseline_on_a_csv_equals_the_predictor_in_python(name, tmp_path):
    rng = np.random.default_rng(0)
    ys = [rng.normal(size=(40, 2)), rng.normal(size=(33, 2))]
    write_long_csv(tmp_path / "d.csv", ys)
    assert main(["predict", name, str(tmp_path / "d.csv"), "--out", str(tmp_path / "p.csv")]) == 0
    pred = read_long_csv(tmp_path / "p.csv")
    for i, y in enumerate(ys):
        ref = make_predictor(name).predict(Trajectories(y=torch.tensor(y[None], dtype=torch.float32)))
        np.testing.assert_allclose(pred[f"r{i}"], ref[0].numpy(), rtol=1e-6, atol=1e-6)


def _simulate(tmp_path, family="linear", extra=()):
    path = tmp_path / "sim.npz"
    argv = ["simulate", family, "--systems", "3", "--horizon", "30", "--out", str(path), *extra]
    assert main(argv) == 0
    d = np.load(path)
    arrays = {k[6:]: d[k] for k in d.files if k.startswith("param_")}
    params = FAMILIES.get(family).Params.from_arrays(arrays, by="the test", where=str(path))
    u = torch.from_numpy(d["u"]) if "u" in d.files else None
    return path, Trajectories(y=torch.from_numpy(d["y"]), u=u, params=params, family=str(d["family"]))


@pytest.mark.parametrize("family, name", [("linear", "kalman"), ("quadrotor", "ekf")])
def test_system_predictor_on_a_simulated_npz_equals_make_predictor(family, name, tmp_path):
    path, traj = _simulate(tmp_path, family)
    assert main(["predict", name, str(path), "--out", str(tmp_path / "p.npz")]) == 0
    yhat = np.load(tmp_path / "p.npz")["yhat"]
    assert yhat.shape == tuple(traj.y.shape)
    np.testing.assert_allclose(yhat, make_predictor(name).predict(traj).numpy(), rtol=1e-5, atol=1e-5)


def test_steps_writes_the_forecasts_and_prints_errors_per_horizon(tmp_path, capsys):
    path, traj = _simulate(tmp_path)
    argv = ["predict", "kalman", str(path), "--steps", "3", "--out", str(tmp_path / "p.npz")]
    assert main(argv) == 0
    yhat = np.load(tmp_path / "p.npz")["yhat"]
    ref = forecast(make_predictor("kalman"), traj, 3).numpy()
    assert yhat.shape == (3, 31, 3, traj.output_dim)
    np.testing.assert_allclose(yhat, ref, rtol=1e-5, atol=1e-5, equal_nan=True)
    out = capsys.readouterr().out
    e3 = np.linalg.norm(traj.y.numpy()[:, 3:] - ref[:, 1:29, 2], axis=-1).mean()
    assert f"{e3:.4g}" in out  # k = 3 over t >= 1
    assert main(["predict", "rls", str(path), "--steps", "2", "--out", str(tmp_path / "p.csv")]) == 0
    rows = list(csv.reader(open(tmp_path / "p.csv")))
    assert rows[0][:3] == ["trajectory", "t", "j"] and len(rows) == 1 + 3 * (31 + 30)


def test_missing_params_and_csv_give_one_line_and_exit_2(tmp_path, capsys):
    path, _ = _simulate(tmp_path)
    d = dict(np.load(path))
    del d["param_A"], d["param_C"]
    np.savez(tmp_path / "bad.npz", **d)
    assert main(["predict", "kalman", str(tmp_path / "bad.npz")]) == 2
    err = capsys.readouterr().err.strip()
    assert "kalman needs param_A, param_C in" in err and "mop simulate" in err and "\n" not in err
    write_long_csv(tmp_path / "d.csv", [np.zeros((5, 2))])
    assert main(["predict", "ekf", str(tmp_path / "d.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert "a CSV has no system parameters" in err and "\n" not in err


def test_unknown_predictor_lists_the_registered_ones(tmp_path, capsys):
    write_long_csv(tmp_path / "d.csv", [np.zeros((5, 2))])
    assert main(["predict", "kalmann", str(tmp_path / "d.csv")]) == 2
    err = capsys.readouterr().err
    assert "'kalmann'" in err and "rls-best" in err and "kalman" in err


def test_forecast_analysis_and_figure_on_a_tiny_experiment(tmp_path):
    from mop.config import SystemConfig
    from mop.experiments.analyses import ANALYSES, horizon_errors
    from mop.experiments.figures import FIGURES
    from mop.experiments.spec import Experiment
    from mop.systems import FAMILIES

    traj = FAMILIES.get("linear")(SystemConfig()).generate(4, 30, generator=torch.Generator().manual_seed(0))
    preds = [make_predictor(n) for n in ("kalman", "rls", "last")]
    result = types.SimpleNamespace(traj=traj, extras={})
    extras = ANALYSES.get("forecast")(result, preds, "kalman")["forecast"]
    assert extras["k"] == list(range(1, 11)) and extras["start"] == 20
    f = forecast(preds[0], traj, 10)
    e = np.linalg.norm((traj.y[:, 24:] - f[:, 20:27, 4]).double().numpy(), axis=-1).mean()
    np.testing.assert_allclose(extras["error"]["kalman"][4], e, rtol=1e-6)
    assert horizon_errors(traj.y, f, 20)[0] < extras["error"]["last"][9]
    result.extras = {"forecast": extras}
    exp = Experiment(
        "tiny", "tiny", {}, ("kalman", "rls", "last"), analyses=("forecast",), figures=("forecast",)
    )
    paths = FIGURES.get("forecast")(exp, {"test": result}, tmp_path)
    assert [p.name for p in paths] == ["tiny_forecast.png", "tiny_forecast.pdf"] and all(
        p.exists() for p in paths
    )
