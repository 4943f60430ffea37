"""`mop fit` then `mop predict MODEL`: end to end on a small record, the written simulation equal to the
library's, and bad input refused in one line before any fit."""

import csv

import numpy as np
import pytest
import torch

from mop.cli import main
from mop.identify import load
from mop.systems.base import Trajectories


def write_record(path, N, rng, gap=False, inputs=True):
    """A known 2-state SISO system with an offset, one trajectory, long CSV; gap: one empty output cell."""
    A, B, C = np.array([[0.9, 0.3], [-0.3, 0.8]]), np.array([0.0, 1.0]), np.array([1.0, 0.5])
    u, x, rows = rng.normal(size=N), np.zeros(2), []
    for t in range(N):
        y = C @ x + 2.0 + 0.05 * rng.normal()
        rows.append(["a", t, "" if gap and t == 7 else f"{y:.9g}"] + ([f"{u[t]:.9g}"] if inputs else []))
        x = A @ x + B * u[t]
    with open(path, "w", newline="") as f:
        csv.writer(f).writerows([["trajectory", "t", "y0"] + (["u0"] if inputs else [])] + rows)
    return path


def read_column(path, name):
    with open(path) as f:
        return np.array([float(r[name]) for r in csv.DictReader(f)])


@pytest.mark.parametrize("kind", ["arx", "n4sid"])
def test_fit_then_predict_end_to_end(kind, tmp_path, capsys):
    rng = np.random.default_rng(0)
    est, val = write_record(tmp_path / "est.csv", 300, rng), write_record(tmp_path / "val.csv", 120, rng)
    model = tmp_path / "model"
    assert main(["fit", kind, str(est), "--out", str(model), "--max-order", "3"]) == 0
    out = capsys.readouterr().out
    assert "held-out rmse" in out and "chosen" in out and (model / "fitted.json").is_file()
    sim_path = tmp_path / "sim.csv"
    assert main(["predict", str(model), str(val), "--simulate", "20", "--out", str(sim_path)]) == 0
    assert "sim rmse" in capsys.readouterr().out
    y, u = read_column(val, "y0"), read_column(val, "u0")
    tr = Trajectories(y=torch.from_numpy(y)[None, :, None], u=torch.from_numpy(u)[None, :, None])
    expected = load(model).simulate(tr, 20)[0, :, 0].numpy()
    np.testing.assert_allclose(read_column(sim_path, "ysim0"), expected, atol=1e-5)
    assert np.sqrt(((expected - y[20:]) ** 2).mean()) < 0.5 * y.std()  # it learned the system
    pred_path = tmp_path / "pred.csv"
    assert main(["predict", str(model), str(val), "--out", str(pred_path)]) == 0
    np.testing.assert_allclose(read_column(pred_path, "yhat0"), load(model).predict(tr)[0, :, 0], atol=1e-5)


def test_bad_input_is_refused_in_one_line(tmp_path, capsys):
    rng = np.random.default_rng(1)

    def error(argv):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and err.startswith("mop: error:"), err
        return err

    gappy = write_record(tmp_path / "gap.csv", 200, rng, gap=True)
    assert "1 output(s) missing" in error(["fit", "arx", str(gappy), "--out", str(tmp_path / "m")])
    short = write_record(tmp_path / "short.csv", 30, rng)
    assert "use --max-order" in error(["fit", "n4sid", str(short), "--out", str(tmp_path / "m")])
    assert "--max-order must be" in error(
        ["fit", "arx", str(short), "--out", str(tmp_path / "m"), "--max-order", "0"]
    )
    est = write_record(tmp_path / "est.csv", 200, rng)
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "config.json").write_text("{}")
    assert "not a fitted model" in error(["fit", "arx", str(est), "--out", str(tmp_path / "run")])
    assert not (tmp_path / "m").exists()
    assert main(["fit", "arx", str(est), "--out", str(tmp_path / "m"), "--max-order", "2"]) == 0
    no_inputs = write_record(tmp_path / "no_u.csv", 50, rng, inputs=False)
    assert "fitted on 1 output(s) and 1 input(s)" in error(["predict", str(tmp_path / "m"), str(no_inputs)])
    (tmp_path / "m" / "fitted.json").write_text("{not json")
    assert "damaged" in error(["predict", str(tmp_path / "m"), str(est)])


def write_ar2(path, N, a1, a2, seed=0):
    """Noise-free y_{t+1} = a1 y_t + a2 y_{t-1} + u_t, one trajectory, long CSV."""
    u, y = np.random.default_rng(seed).normal(size=N), np.zeros(N)
    for t in range(1, N - 1):
        y[t + 1] = a1 * y[t] + a2 * y[t - 1] + u[t]
    rows = [["a", t, repr(float(y[t])), repr(float(u[t]))] for t in range(N)]
    with open(path, "w", newline="") as f:
        csv.writer(f).writerows([["trajectory", "t", "y0", "u0"], *rows])
    return path


@pytest.mark.parametrize("a1, a2, unstable", [(1.5, -0.7, False), (1.9, -0.88, True)])
def test_fit_records_the_poles_and_warns_of_an_unstable_model(a1, a2, unstable, tmp_path, capsys):
    """fitted.json's pole_radius is the largest root modulus of z^2 - a1 z - a2 (numpy.roots) for a
    noise-free ARX(2, 1) record, and `mop fit` warns in one line on stderr where it is >= 1 (1.9, -0.88:
    1.1)."""
    est = write_ar2(tmp_path / "est.csv", 60, a1, a2)
    assert main(["fit", "arx", str(est), "--out", str(tmp_path / "m"), "--max-order", "3"]) == 0
    err = capsys.readouterr().err
    expected = np.abs(np.roots([1.0, -a1, -a2])).max()
    assert load(tmp_path / "m").info["pole_radius"] == pytest.approx(expected, rel=1e-6)
    prefix = "mop: warning: the chosen model is unstable"  # mop's one-line warnings (mop.cli)
    warnings = [line for line in err.splitlines() if line.startswith(prefix)]
    assert len(warnings) == int(unstable)
    assert not unstable or f"{expected:.4g}" in warnings[0]
