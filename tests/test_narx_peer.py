"""The narx peer (`mop benchmark --predictors narx`): sysidentpy's FROLS with its defaults under mop's
protocol. On a plant inside its model class (a degree-2 polynomial NARX of lags <= 2, noiseless) the fit is
exact, so a free run after n measured outputs reproduces the record's y_n..: an off-by-one in the
initial condition or the inputs' alignment would not. Without sysidentpy the command says how to install it,
in one line, before any work."""

import json

import numpy as np
import pytest
import torch

from mop.cli import main
from mop.errors import MopError
from mop.peers import narx
from mop.record import Record
from mop.systems.base import Trajectories
from tests.peer_helpers import refused_without_library, without_library, write_split


def polynomial_plant(steps: int, seed: int) -> Record:
    """y_t = 0.5 y_{t-1} - 0.2 y_{t-2} + 0.3 u_{t-1} + 0.1 u_{t-1}^2 + 0.05 y_{t-1} u_{t-2}."""
    rng = np.random.default_rng(seed)
    u, y = rng.uniform(-1, 1, size=steps), np.zeros(steps)
    for t in range(2, steps):
        y[t] = (
            0.5 * y[t - 1]
            - 0.2 * y[t - 2]
            + 0.3 * u[t - 1]
            + 0.1 * u[t - 1] ** 2
            + 0.05 * y[t - 1] * u[t - 2]
        )
    return Record(y=y, u=u)


def test_a_free_run_after_n_measured_outputs_reproduces_a_plant_in_its_class():
    pytest.importorskip("sysidentpy")
    fitted = narx.fit_narx([polynomial_plant(1500, 0)])
    test = polynomial_plant(400, 1)
    traj = Trajectories(torch.from_numpy(test.y)[None], torch.from_numpy(test.u)[None])
    for n in (fitted.max_lag, 20):
        sim = fitted.simulate(traj, n)  # (1, T+1-n, 1): y_n..y_T
        assert sim.shape == (1, 400 - n, 1)
        np.testing.assert_allclose(sim[0].numpy(), test.y[n:], atol=1e-6)
    with pytest.raises(MopError, match="from 2 measured outputs"):
        fitted.simulate(traj, 1)


def test_two_outputs_are_refused_in_one_line():
    pytest.importorskip("sysidentpy")
    two = Record(y=np.zeros((50, 2)), u=np.zeros(50))
    with pytest.raises(MopError, match="one output"):
        narx.fit_narx([two])


def test_without_sysidentpy_the_benchmark_names_the_install_before_any_work(tmp_path, capsys, monkeypatch):
    without_library(monkeypatch, narx, "sysidentpy")
    refused_without_library(
        write_split(polynomial_plant(300, 2), tmp_path, 200), "narx", narx.INSTALL, tmp_path / "out", capsys
    )


def test_the_benchmark_scores_the_narx_beside_the_arx(tmp_path):
    pytest.importorskip("sysidentpy")
    argv = write_split(polynomial_plant(900, 3), tmp_path, 600)
    out = tmp_path / "out"
    assert main([*argv, "--predictors", "arx,narx", "--init-window", "10", "--out", str(out), "--quiet"]) == 0
    scores = json.loads((out / "results.json").read_text())["est"]["val"]
    assert scores["narx"]["rmse"] < 1e-5 < scores["arx"]["rmse"]  # the plant is in the NARX's class
