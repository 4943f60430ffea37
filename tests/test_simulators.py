"""mop.simulators: the LRU's parallel scan equals its step-by-step loop, the simulation loss's gradient
equals finite differences, training and prediction run the same rollout, the same seed gives the same
weights, and a fit on a linear plant simulates held-out data well."""

import numpy as np
import pytest
import torch

from mop.errors import MopError
from mop.record import Record
from mop.simulators import LRU, DeepLRU, SimulatorConfig, fit_simulator
from mop.simulators.fit import Simulator
from mop.systems.base import Trajectories


def test_the_parallel_scan_equals_the_loop():
    torch.manual_seed(0)
    lru = LRU(4, 6).double()
    u = torch.randn(3, 37, 4, dtype=torch.float64)
    h0 = torch.randn(3, 6, dtype=torch.complex128)
    (y_scan, x_scan), (y_loop, x_loop) = lru(u, h0), lru.loop(u, h0)
    torch.testing.assert_close(y_scan, y_loop, rtol=0, atol=1e-12)
    torch.testing.assert_close(x_scan, x_loop, rtol=0, atol=1e-12)
    deep = DeepLRU(2, 1, 8, 5, 2).double()
    u = torch.randn(2, 50, 2, dtype=torch.float64)
    h0 = [torch.randn(2, 5, dtype=torch.complex128) for _ in range(2)]
    torch.testing.assert_close(deep(u, h0), deep(u, h0, loop=True), rtol=0, atol=1e-12)


def test_every_eigenvalue_is_inside_the_unit_circle():
    lru = LRU(8, 64)
    with torch.no_grad():
        lru.nu_log.uniform_(-8, 3)
        lru.theta_log.uniform_(-3, 3)
    assert (lru.lam().abs() < 1).all()


def test_the_simulation_loss_gradient_equals_finite_differences():
    torch.manual_seed(1)
    cfg = SimulatorConfig(init_window=3, width=4, state=3, layers=1, encoder_width=5)
    model = Simulator(1, 1, cfg).double()
    window, future, target = (torch.randn(2, 3, 2), torch.randn(2, 9, 1), torch.randn(2, 9, 1))
    window, future, target = window.double(), future.double(), target.double()

    def loss():
        return ((model.simulate_segment(window, future) - target) ** 2).mean()

    loss().backward()
    for param in (model.body.lrus[0].nu_log, model.body.lrus[0].B_im, model.encoder[0].weight):
        analytic = param.grad.flatten()[0].item()
        with torch.no_grad():
            h = 1e-6
            param.view(-1)[0] += h
            up = loss().item()
            param.view(-1)[0] -= 2 * h
            down = loss().item()
            param.view(-1)[0] += h
        assert analytic == pytest.approx((up - down) / (2 * h), rel=1e-5, abs=1e-9)


def plant(n, seed):
    """A lightly damped second-order plant with one input and a little output noise."""
    rng = np.random.default_rng(seed)
    u, y = rng.normal(size=n), np.zeros(n)
    for t in range(2, n):
        y[t] = 1.5 * y[t - 1] - 0.7 * y[t - 2] + 0.5 * u[t - 1] + 0.3 * np.tanh(u[t - 1])
    return Record(y=y + 0.01 * rng.normal(size=n), u=u)


SMALL = SimulatorConfig(init_window=10, subsection=60, width=16, state=16, layers=1, steps=300, batch=16)


@pytest.fixture(scope="module")
def fitted():
    return fit_simulator([plant(1500, 0)], SMALL)


def test_a_fit_simulates_held_out_data_of_its_plant(fitted):
    """Tolerance: the simulation NRMSE on a new record of the plant (its own noise 1% of the output's std)
    below 0.25 after 300 steps; the initial network simulates it at about 1."""
    test = plant(600, 1)
    traj = Trajectories(y=torch.from_numpy(test.y)[None], u=torch.from_numpy(test.u)[None])
    sim = fitted.simulate(traj, 10)[0].numpy()
    nrmse = np.sqrt(np.mean((sim - test.y[10:]) ** 2)) / test.y[10:].std()
    assert nrmse < 0.25, nrmse
    assert fitted.info["held_out_rmse"] < 0.5 * fitted.info["initial_held_out_rmse"]


def test_prediction_runs_the_rollout_training_runs(fitted):
    """simulate(traj, c) is simulate_segment on the normalised window before c and the inputs after it."""
    test = plant(200, 2)
    traj = Trajectories(y=torch.from_numpy(test.y)[None], u=torch.from_numpy(test.u)[None])
    s = fitted.scaling
    y, u = s.z(test.y, test.u)
    window = torch.from_numpy(np.concatenate([y[30:40], u[30:40]], axis=-1))[None]
    with torch.no_grad():
        direct = fitted.model.simulate_segment(window, torch.from_numpy(u[40:])[None])[0].numpy()
    np.testing.assert_allclose(fitted.simulate(traj, 40)[0].numpy(), direct * s.y_std + s.y_mean, atol=1e-12)
    one_step = fitted.predict(traj)[0].numpy()
    np.testing.assert_allclose(one_step[40], fitted.simulate(traj, 40)[0, 0].numpy(), atol=1e-12)


def test_the_same_seed_gives_the_same_weights():
    cfg = SimulatorConfig(init_window=5, subsection=20, width=4, state=4, layers=1, steps=5, batch=4)
    a, b = (fit_simulator([plant(300, 3)], cfg) for _ in range(2))
    for (name, x), (_, y) in zip(a.model.state_dict().items(), b.model.state_dict().items(), strict=True):
        assert torch.equal(x, y), name
    c = fit_simulator([plant(300, 3)], SimulatorConfig(**{**cfg.__dict__, "seed": 1}))
    assert not torch.equal(c.model.body.read_out.weight, a.model.body.read_out.weight)


def test_bad_records_are_one_line():
    with pytest.raises(MopError, match="input column u0"):
        fit_simulator([Record(y=np.zeros(500))], SMALL)
    with pytest.raises(MopError, match="too short"):
        fit_simulator([plant(30, 0)], SMALL)


def test_mop_benchmark_scores_the_simulator_under_the_protocol(tmp_path, monkeypatch, capsys):
    import functools
    import json

    from mop.cli import main
    from mop.commands import benchmark
    from mop.record import write_records

    small = functools.partial(SimulatorConfig, subsection=30, width=4, state=4, layers=1, steps=20, batch=4)
    monkeypatch.setattr(benchmark, "SimulatorConfig", small)
    write_records([Record(y=plant(600, 0).y, u=plant(600, 0).u, name="est")], tmp_path / "est.csv")
    write_records([Record(y=plant(300, 1).y, u=plant(300, 1).u, name="val")], tmp_path / "val.csv")
    argv = ["benchmark", "--est", str(tmp_path / "est.csv"), "--test", str(tmp_path / "val.csv")]
    assert (
        main([*argv, "--init-window", "10", "--predictors", "lru", "--out", str(tmp_path / "b"), "--quiet"])
        == 0
    )
    score = json.loads((tmp_path / "b" / "results.json").read_text())["est"]["val"]["lru"]
    written = np.genfromtxt(tmp_path / "b" / "est" / "val_lru.csv", delimiter=",", names=True)
    assert written["t"][0] == 10 and score["n"] == 10
    assert np.sqrt(np.mean((written["y0"] - written["ysim0"]) ** 2)) == pytest.approx(score["rmse"], rel=1e-5)
    assert "deep LRU (1 x 4, state 4)" in (tmp_path / "b" / "report.md").read_text()


def test_the_estimator_face_simulates_a_record_in_its_units():
    from mop.estimators import LRU as LRUEstimator

    est, val = plant(800, 4).split(0.3)
    model = LRUEstimator(init_window=10, steps=5, subsection=40, width=4, state=4, layers=1, batch=4).fit(est)
    sim = model.simulate(val, init=10)
    assert np.isnan(sim[:10]).all() and np.isfinite(sim[10:]).all()
    traj = Trajectories(y=torch.from_numpy(val.y)[None], u=torch.from_numpy(val.u)[None])
    np.testing.assert_allclose(sim[10:], model.predictor_.simulate(traj, 10)[0].numpy(), atol=1e-5)
    with pytest.raises(MopError, match="unknown option"):
        LRUEstimator(steps=5, depth=3)
