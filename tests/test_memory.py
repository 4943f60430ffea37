"""mop.memory and its callers: a job that cannot fit is refused with the number before it allocates;
--steps beyond the data's horizon is refused; forecasts past a short trajectory's end are NaN, not a crash."""

import numpy as np
import pytest
import torch

from mop.cli import main
from mop.errors import MopError
from mop.memory import check_allocation, memory_limit


def _one_line(capsys, *words):
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1 and all(w in err for w in words), err


def test_the_limit_comes_from_the_environment(monkeypatch):
    monkeypatch.setenv("MOP_MEMORY_LIMIT_GB", "2")
    assert memory_limit() == (2e9, "MOP_MEMORY_LIMIT_GB=2")
    check_allocation(1.9e9, "a job", "shrink it")
    with pytest.raises(MopError, match=r"a job needs about 2.1 GB of memory, above the limit of 2 GB"):
        check_allocation(2.1e9, "a job", "shrink it")
    monkeypatch.setenv("MOP_MEMORY_LIMIT_GB", "lots")
    with pytest.raises(MopError, match="must be a number of GB"):
        memory_limit()


def test_the_default_limit_is_a_share_of_available_memory(monkeypatch):
    import mop.memory

    monkeypatch.delenv("MOP_MEMORY_LIMIT_GB", raising=False)
    monkeypatch.setattr(mop.memory, "available_bytes", lambda: 10e9)
    assert memory_limit()[0] == pytest.approx(8e9)


def test_simulate_refuses_400_gb_at_once(tmp_path, capsys):
    out = tmp_path / "s.npz"
    argv = ["simulate", "linear", "--systems", "100000", "--horizon", "100000", "--out", str(out)]
    assert main(argv) == 2
    # 3 x 100000 x 100001 x (10 states + 5 outputs) x 4 bytes
    _one_line(capsys, "simulating 100000 systems x 100001 steps x 15 values needs about 1,800 GB")
    assert not out.exists()


def test_simulate_estimate_bounds_the_measured_peak(tmp_path, monkeypatch, capsys):
    """The estimate is 3x the x, y arrays: just below it the job runs, just above the limit it is refused."""
    systems, horizon = 200, 99
    nbytes = 3 * systems * (horizon + 1) * 15 * 4
    monkeypatch.setenv("MOP_MEMORY_LIMIT_GB", str(nbytes * 1.01 / 1e9))
    argv = ["simulate", "linear", "--systems", str(systems), "--horizon", str(horizon)]
    assert main([*argv, "--out", str(tmp_path / "a.npz")]) == 0
    monkeypatch.setenv("MOP_MEMORY_LIMIT_GB", str(nbytes * 0.99 / 1e9))
    assert main([*argv, "--out", str(tmp_path / "b.npz")]) == 2
    assert not (tmp_path / "b.npz").exists()


def test_steps_beyond_the_horizon_are_refused(tmp_path, capsys):
    np.savez(tmp_path / "d.npz", y=np.random.default_rng(0).normal(size=(2, 11, 2)))
    out = tmp_path / "p.npz"
    assert main(["predict", "last", str(tmp_path / "d.npz"), "--steps", "100000", "--out", str(out)]) == 2
    _one_line(capsys, "--steps 100000", "T = 10", "use --steps <= 11")
    assert not out.exists()


def test_steps_past_a_short_trajectory_give_nan_not_a_crash(tmp_path, capsys):
    """K = 14 > T + 2 of the 6-step trajectory (the longer one has T = 20): per-k errors count only the
    pairs with a target; the short one's forecasts beyond its end are absent from the CSV."""
    from tests.reference import write_long_csv

    rng = np.random.default_rng(1)
    write_long_csv(tmp_path / "d.csv", [rng.normal(size=(7, 2)), rng.normal(size=(21, 2))])
    out = tmp_path / "p.csv"
    assert main(["predict", "last", str(tmp_path / "d.csv"), "--steps", "14", "--out", str(out)]) == 0
    table = [line for line in capsys.readouterr().out.splitlines() if not line.startswith("predictor:")]
    counts = {int(r.split()[0]): int(r.split()[1]) for r in table[1:15]}
    assert counts == {k: (6 - k + 1 if k <= 6 else 0) + (20 - k + 1) for k in range(1, 15)}


def test_forecast_checks_its_size(monkeypatch):
    from mop.predictors import forecast, make_predictor
    from mop.systems.base import Trajectories

    monkeypatch.setenv("MOP_MEMORY_LIMIT_GB", "1e-6")  # 1000 bytes
    traj = Trajectories(y=torch.zeros(2, 11, 2))
    forecast(make_predictor("last"), traj, 2)  # 2 x 2 x 11 x 2 x 2 x 4 = 704 bytes
    with pytest.raises(MopError, match="a 3-step forecast of 2 trajectories x 11 steps needs about"):
        forecast(make_predictor("last"), traj, 3)
