"""Free-run simulation: after a context of c outputs, y_c..y_T from the inputs alone. Every predictor's
simulate equals its k-step forecast from origin c; the Kalman filter's equals the noise-free rollout of
the model from the filtered state; no output after the context is read."""

import numpy as np
import pytest
import torch

from mop.config import RunConfig, SystemConfig, apply_overrides
from mop.errors import MopError
from mop.predictors import forecast, make_predictor, simulate
from mop.runs import load_predictor
from mop.systems import Trajectories, generator, make_family

CONTEXT = 14


@pytest.fixture(scope="module")
def traj():
    cfg = SystemConfig(family="linear-inputs", state_dim=3, output_dim=2, input_dim=2)
    return make_family(cfg, torch.float64).generate(4, 24, generator=generator(0))


@pytest.fixture(scope="module")
def tiny_inputs_run(tmp_path_factory):
    from mop.train import train

    cfg = apply_overrides(
        RunConfig(),
        [
            "system.family=linear-inputs",
            "system.output_dim=2",
            "system.state_dim=3",
            "model.num_layers=1",
            "model.width=16",
            "model.num_heads=2",
            "model.context=10",
            "train.steps=3",
            "train.horizon=10",
        ],
    )
    return train(cfg, tmp_path_factory.mktemp("run") / "tiny", progress=False)


@pytest.mark.parametrize(
    "name", ["kalman", "ekf", "ukf", "arx", "arx-best", "n4sid-kf", "last", "zero", "rls"]
)
def test_simulate_is_the_forecast_from_the_context(traj, name):
    p = make_predictor(name)
    sim = simulate(p, traj, CONTEXT)
    assert sim.shape == (4, traj.horizon + 1 - CONTEXT, 2)
    ref = forecast(p, traj, traj.horizon + 1 - CONTEXT)[:, CONTEXT]
    np.testing.assert_allclose(sim, ref, rtol=1e-9, atol=1e-10)


def test_learned_simulate_is_its_forecast_from_the_context(traj, tiny_inputs_run):
    p = load_predictor(tiny_inputs_run)
    traj32 = traj._map(lambda t: t.float())
    sim = simulate(p, traj32, CONTEXT)
    ref = forecast(p, traj32, traj.horizon + 1 - CONTEXT)[:, CONTEXT]
    np.testing.assert_allclose(sim, ref, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("name", ["kalman", "arx", "n4sid-kf", "last"])
def test_simulation_reads_no_output_after_the_context(traj, name):
    changed = traj._map(lambda t: t.clone())
    changed.y[:, CONTEXT:] = 1e3
    p = make_predictor(name)
    np.testing.assert_array_equal(simulate(p, traj, CONTEXT), simulate(p, changed, CONTEXT))


def test_kalman_simulation_is_the_noise_free_model_rollout(traj):
    """The first simulated output is the one-step prediction; a unit change of one future input u_s moves
    the simulation by C A^(j-1) B du at j steps after s, and nothing before (numpy closed form)."""
    sim = simulate(make_predictor("kalman"), traj, CONTEXT).numpy()
    one_step = make_predictor("kalman").predict(traj).numpy()
    A, B, C = (M.numpy() for M in (traj.params.A, traj.params.B, traj.params.C))
    u = traj.u.numpy()
    np.testing.assert_allclose(sim[:, 0], one_step[:, CONTEXT], rtol=1e-10)
    # the input's contribution: two rollouts differing only in the future inputs differ by C A^i B du
    changed = traj._map(lambda t: t.clone())
    du = np.zeros_like(u)
    du[:, CONTEXT + 2] = 1.0
    changed.u[:, CONTEXT + 2] += 1.0
    delta = simulate(make_predictor("kalman"), changed, CONTEXT).numpy() - sim
    for j in range(3, sim.shape[1]):
        expected = np.einsum("bmn,bnk,bk->bm", C @ np.linalg.matrix_power(A, j - 3), B, du[:, CONTEXT + 2])
        np.testing.assert_allclose(delta[:, j], expected, rtol=1e-9, atol=1e-12)
    assert np.abs(delta[:, :3]).max() == 0


def test_bad_context_is_refused(traj):
    for bad in (-1, traj.horizon + 1, 2.5):  # 0 is accepted: it means --simulate 0 (context 1)
        with pytest.raises(MopError, match="simulation context"):
            simulate(make_predictor("last"), traj, bad)


def test_predict_simulate_writes_the_simulation_and_prints_both_errors(tmp_path, capsys):
    from mop.cli import main

    path = tmp_path / "sim.npz"
    argv = ["simulate", "linear-inputs", "--systems", "3", "--horizon", "30", "--out", str(path)]
    assert main([*argv, "state_dim=3", "output_dim=2"]) == 0
    capsys.readouterr()
    assert main(["predict", "arx", str(path), "--simulate", "20", "--out", str(tmp_path / "p.npz")]) == 0
    printed = capsys.readouterr().out
    assert "1-step rmse" in printed and "sim rmse" in printed and "sim fit %" in printed
    d = np.load(path)
    traj = Trajectories(y=torch.from_numpy(d["y"]), u=torch.from_numpy(d["u"]))
    ref = simulate(make_predictor("arx"), traj, 20).numpy()
    np.testing.assert_allclose(np.load(tmp_path / "p.npz")["ysim"], ref, rtol=1e-5, atol=1e-5)
    # the overall line: RMSE and fit % (per channel 100 (1 - ||y - ysim|| / ||y - mean y||), then averaged)
    y = d["y"][:, 20:].reshape(-1, 2)
    e = y - ref.reshape(-1, 2)
    fit = 100 * (1 - np.linalg.norm(e, axis=0) / np.linalg.norm(y - y.mean(0), axis=0)).mean()
    overall = next(line for line in printed.splitlines() if line.split()[0] == "overall").split()
    assert float(overall[4]) == pytest.approx(np.sqrt((e**2).mean()), rel=1e-3)
    assert float(overall[6]) == pytest.approx(fit, abs=0.01)
    assert main(["predict", "arx", str(path), "--simulate", "31"]) == 2
    err = capsys.readouterr().err.strip()
    assert "--simulate must be in [0, 30]" in err and "\n" not in err
    # --simulate 0: from the start, y_0 the initial condition: the simulation after one output
    assert main(["predict", "arx", str(path), "--simulate", "0", "--out", str(tmp_path / "p0.npz")]) == 0
    ref1 = simulate(make_predictor("arx"), traj, 1).numpy()
    np.testing.assert_allclose(np.load(tmp_path / "p0.npz")["ysim"], ref1, rtol=1e-5, atol=1e-5)
