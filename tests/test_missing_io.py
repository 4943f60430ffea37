"""Missing outputs in files: an empty CSV cell or NaN marks a missing output; Inf, garbage and missing inputs
are refused naming line and column; `mop predict` and `mop train --data` take files with gaps."""

import numpy as np
import pytest
import torch

from mop.cli import main
from mop.errors import MopError
from mop.io import read_trajectories
from mop.missing import drop_mask, drop_outputs
from tests.reference import linear_traj
from tests.test_missing_model import gen


def write(path, text):
    path.write_text(text)
    return path


def test_empty_cells_and_nan_read_as_missing(tmp_path):
    text = "trajectory,t,y0,y1,u0\na,0,1,2,0\na,1,,3,0\na,2,nan, 4 ,1\nb,0,1,,0\nb,1,2,2,0\n"
    p = write(tmp_path / "d.csv", text)
    names, data = read_trajectories(p)
    (ya, ua), (yb, _) = data
    assert names == ["a", "b"] and np.isnan(ya[1, 0]) and np.isnan(ya[2, 0]) and ya[2, 1] == 4.0
    assert np.isnan(yb[0, 1]) and not np.isnan(ua).any()


@pytest.mark.parametrize(
    "row,message",
    [
        ("a,1,inf,3,0", "line 3, column y0: 'inf' is infinite"),
        ("a,1,abc,3,0", "line 3, column y0: 'abc' is not a number"),
        ("a,1,1,3,", "line 3, column u0: the input is missing"),
        ("a,1,1,3,NaN", "line 3, column u0: the input is missing"),
        ("a,x,1,3,0", "line 3, column t: 'x' is neither a time step"),
    ],
)
def test_bad_cells_name_line_and_column(tmp_path, row, message):
    p = write(tmp_path / "d.csv", f"trajectory,t,y0,y1,u0\na,0,1,2,0\n{row}\n")
    with pytest.raises(MopError, match=message) as err:
        read_trajectories(p)
    assert "\n" not in str(err.value)


def test_npz_gaps_in_y_kept_inf_and_missing_u_refused(tmp_path):
    y = np.ones((2, 5, 2))
    y[0, 2, 1] = np.nan
    np.savez(tmp_path / "ok.npz", y=y)
    assert np.isnan(read_trajectories(tmp_path / "ok.npz")[1][0][0][2, 1])
    u = np.zeros((2, 5, 1))
    u[1, 3] = np.nan
    np.savez(tmp_path / "u.npz", y=y, u=u)
    with pytest.raises(MopError, match="inputs u must be complete"):
        read_trajectories(tmp_path / "u.npz")
    y[1, 1, 0] = np.inf
    np.savez(tmp_path / "inf.npz", y=y)
    with pytest.raises(MopError, match="y holds Inf"):
        read_trajectories(tmp_path / "inf.npz")
    np.savez(tmp_path / "empty.npz", y=np.full((2, 5, 2), np.nan))
    with pytest.raises(MopError, match="trajectory 0 has no measured output"):
        read_trajectories(tmp_path / "empty.npz")


def gappy_file(tmp_path, num=12, horizon=14):
    traj = linear_traj(num_systems=num, horizon=horizon)
    y = drop_outputs(traj.y, drop_mask(tuple(traj.y.shape), 0.2, gen(5))).numpy()
    path = tmp_path / "gaps.npz"
    np.savez(path, **{**traj.to_numpy_dict(), "y": y})
    return path


def test_predict_cli_with_gaps(tmp_path, capsys, tiny_run):
    path = gappy_file(tmp_path)
    for name in ("rls", "last", "kalman"):
        assert main(["predict", name, str(path), "--out", str(tmp_path / f"{name}.npz")]) == 0
        with np.load(tmp_path / f"{name}.npz") as f:
            assert np.isfinite(f["yhat"]).all()
        assert "nan" not in capsys.readouterr().out.lower()  # errors over the measured outputs
    assert main(["predict", "n4sid-kf", str(path), "--out", str(tmp_path / "n.npz")]) == 2
    assert "n4sid-kf needs every output" in capsys.readouterr().err
    assert main(["predict", str(tiny_run), str(path), "--out", str(tmp_path / "m.npz")]) == 2
    err = capsys.readouterr().err.strip()
    assert "trained without them" in err and "\n" not in err and not (tmp_path / "m.npz").exists()


def test_train_data_with_gaps_needs_the_mask_then_predicts(tmp_path, capsys):
    path = gappy_file(tmp_path)
    tiny = ["model.num_layers=1", "model.width=16", "model.num_heads=2", "model.context=8"]
    tiny += ["train.horizon=8", "train.batch_size=8", "train.steps=4", "train.compile=off"]
    common = ["train", "--data", str(path), "--no-progress", *tiny]
    assert main([*common, "--out", str(tmp_path / "plain")]) == 2
    assert "model.observation_mask=true" in capsys.readouterr().err
    assert not (tmp_path / "plain").exists()
    run = tmp_path / "masked"
    assert main([*common, "--out", str(run), "train.missing_rate=0.1"]) == 0
    assert main(["predict", str(run), str(path), "--out", str(tmp_path / "p.npz"), "--steps", "2"]) == 0
    with np.load(tmp_path / "p.npz") as f:
        assert np.isfinite(f["yhat"][:, :, 0]).all()


def test_errors_and_ratios_over_the_measured_outputs_only():
    from mop.metrics import errors, mse_ratio_ci

    g = np.random.default_rng(0)
    y, a, b = (g.normal(size=(20, 8, 3)) for _ in range(3))
    y[g.random(y.shape) < 0.3] = np.nan
    y[0, 4] = np.nan  # a whole step
    ea, eb = (errors(torch.from_numpy(p), torch.from_numpy(y)) for p in (a, b))
    ref = np.sqrt(np.nansum((a - y) ** 2, -1))
    ref[np.isnan(y).all(-1)] = np.nan
    np.testing.assert_allclose(ea, ref, rtol=1e-12)
    assert np.isnan(ea[0, 4])
    ratio = mse_ratio_ci(ea, eb, 1, 8)[0]
    expected = np.nansum((a - y)[:, 1:8] ** 2) / np.nansum((b - y)[:, 1:8] ** 2)
    assert ratio == pytest.approx(expected, rel=1e-12)
    full = g.normal(size=(5, 6, 2))
    plain = errors(torch.from_numpy(a[:5, :6, :2]), torch.from_numpy(full))
    np.testing.assert_allclose(plain, np.linalg.norm(a[:5, :6, :2] - full, axis=-1), rtol=1e-14)


def test_condition_missing_is_validated_and_seeded():
    import dataclasses as dc

    from mop.experiments.evaluating import with_missing
    from mop.experiments.spec import Condition

    with pytest.raises(MopError, match="unknown missing keys"):
        Condition("c", missing={"fraction": 0.3})
    with pytest.raises(MopError, match="missing.rate must be in"):
        Condition("c", missing={"rate": 1.5})
    traj = linear_traj(num_systems=200, horizon=50)
    a, b = with_missing(traj, {"rate": 0.3}, 0), with_missing(traj, {"rate": 0.3}, 0)
    assert torch.equal(a.y.isnan(), b.y.isnan()) and not a.y[:, 0].isnan().any()
    assert abs(float(a.y[:, 1:].isnan().double().mean()) - 0.3) < 0.01
    assert dc.replace(a, y=traj.y).observed is None


def test_predict_csv_with_empty_cells(tmp_path, capsys):
    rows = ["trajectory,t,y0,y1"] + [
        f"r{i},{t},{'' if (t * 7 + i) % 4 == 1 else t},{t * 0.5}" for i in range(2) for t in range(12)
    ]
    data = write(tmp_path / "d.csv", "\n".join(rows) + "\n")
    assert main(["predict", "rls", str(data), "--out", str(tmp_path / "p.csv")]) == 0
    lines = (tmp_path / "p.csv").read_text().splitlines()
    assert len(lines) == 1 + 24 and "nan" not in "".join(lines).lower()
    assert "overall" in capsys.readouterr().out
