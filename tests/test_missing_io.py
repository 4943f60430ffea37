"""Missing outputs in files: an empty CSV cell or NaN marks a missing output; Inf, garbage and missing inputs
are refused naming line and column; `mop predict` and `mop train --data` take files with gaps."""

import numpy as np
import pytest

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
        ("a,x,1,3,0", "line 3, column t: 'x' is not an integer"),
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
