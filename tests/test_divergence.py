"""A free run that blows up is reported as diverged at its step with RMSE inf, never scored over its finite
steps (mop.records.divergence_step, mop predict --simulate)."""

import json

import numpy as np
import pytest

from mop.cli import main
from mop.records import DIVERGENCE_FACTOR, divergence_step


def test_divergence_step_is_the_first_non_finite_or_far_out_row():
    y = np.array([[0.0], [1.0], [-1.0], [0.5]])  # range [-1, 1], span 2
    assert divergence_step(y, np.zeros((3, 1))) is None
    assert divergence_step(y, np.array([[0.0], [np.nan], [0.0]])) == 1
    far = 1 + DIVERGENCE_FACTOR * 2
    assert divergence_step(y, np.array([[0.0], [0.0], [far * 0.99], [far * 1.01]])) == 3
    assert divergence_step(y, np.array([[np.inf], [0.0]])) == 0


@pytest.fixture
def record(tmp_path):
    rng = np.random.default_rng(0)
    u = rng.normal(size=300)
    y = np.zeros(300)
    for t in range(1, 300):
        y[t] = 0.9 * y[t - 1] + u[t - 1] + 0.01 * rng.normal()
    path = tmp_path / "rec.csv"
    path.write_text("y0,u0\n" + "\n".join(f"{a:.10g},{b:.10g}" for a, b in zip(y, u, strict=True)) + "\n")
    return path


def test_a_diverging_simulation_prints_inf_and_its_step(tmp_path, record, capsys):
    """An ARX made unstable on purpose (its A x 1.2): the free run overflows, and the summary says so."""
    assert main(["fit", "arx", str(record), "--out", str(tmp_path / "arx")]) == 0
    fitted = tmp_path / "arx" / "fitted.json"
    d = json.loads(fitted.read_text())
    d["model"]["A"] = (1.2 * np.asarray(d["model"]["A"])).tolist()
    fitted.write_text(json.dumps(d))
    capsys.readouterr()
    out = tmp_path / "p.npz"
    assert main(["predict", str(tmp_path / "arx"), str(record), "--simulate", "50", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    overall = next(line for line in printed.splitlines() if line.strip().startswith("overall"))
    assert overall.split()[4] == "inf"
    assert "diverged: the simulation of rec at step" in printed
    step = int(printed.split("at step ")[1].split()[0])
    sim = np.load(out)["ysim"][0]
    assert 50 < step < 300 and np.isfinite(sim[: step - 50]).all()  # finite for a while, then not


def test_a_stable_simulation_is_scored_as_before(tmp_path, record, capsys):
    assert main(["fit", "arx", str(record), "--out", str(tmp_path / "arx")]) == 0
    capsys.readouterr()
    out = tmp_path / "p.npz"
    assert main(["predict", str(tmp_path / "arx"), str(record), "--simulate", "50", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "diverged" not in printed
    y = np.loadtxt(record, delimiter=",", skiprows=1)[50:, 0]
    rmse = np.sqrt(np.mean((np.load(out)["ysim"][0, :, 0] - y) ** 2))
    overall = next(line for line in printed.splitlines() if line.strip().startswith("overall"))
    assert float(overall.split()[4]) == pytest.approx(rmse, rel=1e-3)
