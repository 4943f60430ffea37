"""The subnet peer (`mop benchmark --predictors subnet`): deepSI's SUBNET with its defaults under mop's
protocol. Its free run after n measured outputs is the library's own simulation of the record from there
(an off-by-one in the encoder's window or the inputs' alignment would differ), the same seed trains the same
weights, and without deepSI the command says how to install it, in one line, before any work."""

import json

import numpy as np
import pytest
import torch

from mop.cli import main
from mop.errors import MopError
from mop.peers import subnet
from mop.record import Record
from mop.systems.base import Trajectories
from tests.peer_helpers import refused_without_library, without_library, write_split


@pytest.fixture
def home(tmp_path, monkeypatch):
    """deepSI writes its checkpoints under ~/.deepSI-checkpoints: a HOME of the test's own."""
    pytest.importorskip("deepSI")
    monkeypatch.setenv("HOME", str(tmp_path))
    torch.set_num_threads(1)
    return tmp_path


def plant(steps: int, seed: int) -> Record:
    """y_t = 0.8 y_{t-1} + 0.5 tanh(u_{t-1}) + 0.01 e_t."""
    rng = np.random.default_rng(seed)
    u, y = rng.normal(size=steps), np.zeros(steps)
    for t in range(1, steps):
        y[t] = 0.8 * y[t - 1] + 0.5 * np.tanh(u[t - 1]) + 0.01 * rng.normal()
    return Record(y=y, u=u)


def test_the_free_run_after_n_is_the_librarys_own_simulation_from_there(home):
    fitted = subnet.fit_subnet([plant(300, 0)], init_window=5, seed=0, minutes=0.05)
    assert fitted.window == 5 and fitted.iterations == subnet.iterations(0.05) == 6
    test = plant(200, 1)
    traj = Trajectories(torch.from_numpy(test.y)[None], torch.from_numpy(test.u)[None])
    data = subnet.deepsi().Input_output_data
    for n in (5, 30):
        sim = fitted.simulate(traj, n)  # (1, T+1-n, 1): y_n..y_T
        own = fitted.model.simulate(data(u=test.u[n - 5 :], y=test.y[n - 5 :])).y[5:]
        assert sim.shape == (1, 200 - n, 1)
        np.testing.assert_array_equal(sim[0].numpy(), np.asarray(own).reshape(-1, 1))
    with pytest.raises(MopError, match="from 5 measured outputs"):
        fitted.simulate(traj, 4)


def test_the_same_seed_trains_the_same_model_and_another_seed_another(home):
    test = plant(200, 1)
    traj = Trajectories(torch.from_numpy(test.y)[None], torch.from_numpy(test.u)[None])
    runs = [subnet.fit_subnet([plant(300, 0)], 5, seed=s, minutes=0.02).simulate(traj, 5) for s in (0, 0, 1)]
    assert torch.equal(runs[0], runs[1]) and not torch.equal(runs[0], runs[2])


def test_the_benchmark_scores_it_under_the_protocol(home):
    argv = [*write_split(plant(400, 2), home, 300), "--init-window", "10"]
    out = home / "out"
    assert main([*argv, "--predictors", "arx,subnet", "--budget", "0.01", "--out", str(out), "--quiet"]) == 0
    scores = json.loads((out / "results.json").read_text())["est"]["val"]
    assert set(scores) == {"arx", "subnet"} and np.isfinite(scores["subnet"]["rmse"])
    assert "deepSI SUBNET, its defaults" in (out / "report.md").read_text()


def test_without_deepsi_the_command_is_one_line_before_any_work(tmp_path, capsys, monkeypatch):
    without_library(monkeypatch, subnet, "deepSI")
    refused_without_library(
        write_split(plant(300, 3), tmp_path, 200), "subnet", subnet.INSTALL, tmp_path / "out", capsys
    )
