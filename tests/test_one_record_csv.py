"""One record as identification data comes: a CSV without the trajectory column (`t,y0..,u0..`) or without
both it and t (`y0..,u0..`, rows in time order) reads as the long format's one trajectory."""

import numpy as np
import pytest

from mop.cli import main
from mop.errors import MopError
from mop.io import read_trajectories


def write(path, header: str, rows: list[str]) -> str:
    path.write_text(header + "\n" + "\n".join(rows) + "\n")
    return str(path)


@pytest.fixture
def record():
    rng = np.random.default_rng(0)
    y, u = rng.normal(size=(40, 1)), rng.normal(size=(40, 1))
    y[7] = np.nan  # an output gap: an empty cell
    return y, u


def cells(y, u, t: int) -> str:
    return ("" if np.isnan(y[t, 0]) else repr(float(y[t, 0]))) + "," + repr(float(u[t, 0]))


def test_the_one_record_headers_read_as_the_long_format(tmp_path, record):
    y, u = record
    T = len(y)
    long = write(tmp_path / "long.csv", "trajectory,t,y0,u0", [f"rec,{t},{cells(y, u, t)}" for t in range(T)])
    # rows in any order with t, in time order without it
    with_t = write(tmp_path / "rec.csv", "t,y0,u0", [f"{t},{cells(y, u, t)}" for t in reversed(range(T))])
    bare = write(tmp_path / "bare.csv", "y0,u0", [cells(y, u, t) for t in range(T)])
    (_, [(y0, u0)]) = read_trajectories(long)
    np.testing.assert_array_equal(y0, y)
    np.testing.assert_array_equal(u0, u)
    for path in (with_t, bare):
        names, [(y1, u1)] = read_trajectories(path)
        np.testing.assert_array_equal(y1, y)
        np.testing.assert_array_equal(u1, u)
    assert read_trajectories(with_t)[0] == ["rec"] and read_trajectories(bare)[0] == ["bare"]


def test_one_record_errors_name_the_line_and_the_forms(tmp_path, record):
    y, u = record
    rows = [cells(y, u, t) for t in range(len(y))]
    rows[3] = rows[3].split(",")[0] + ","  # a missing input on line 5 (the header is line 1)
    with pytest.raises(MopError, match=r"line 5, column u0"):
        read_trajectories(write(tmp_path / "gap.csv", "y0,u0", rows))
    with pytest.raises(MopError, match=r"or, for one record, `t,y0..` or `y0..`"):
        read_trajectories(write(tmp_path / "bad.csv", "time,y0,u0", [f"0,{rows[0]}"]))


def test_mop_fit_and_predict_take_a_one_record_csv(tmp_path, capsys):
    rng = np.random.default_rng(1)
    u = rng.normal(size=301)
    y = np.zeros(301)
    for t in range(300):
        y[t + 1] = 0.7 * y[t] + 0.4 * u[t] + 0.01 * rng.normal()
    est = write(
        tmp_path / "est.csv", "y0,u0", [f"{float(a)!r},{float(b)!r}" for a, b in zip(y, u, strict=True)]
    )
    assert main(["fit", "arx", est, "--out", str(tmp_path / "arx")]) == 0
    assert main(["predict", str(tmp_path / "arx"), est, "--out", str(tmp_path / "p.csv")]) == 0
    assert "overall" in capsys.readouterr().out
