"""CSV value columns are read by their names, in any order; a duplicate, a gap in the numbering or an unknown
name is one line naming the column; large units load; an infinite input is not called a missing output."""

import numpy as np
import pytest

from mop.cli import main
from mop.errors import MopError
from mop.io import read_trajectories

ROWS = [(0, 1.0, 10.0), (1, 2.0, 20.0), (2, 3.0, 30.0)]  # (t, y0, u0)


def write(path, header, order):
    """A one-record CSV with `header`, each row's values (t, y0, u0) put in `order` (indices into the row)."""
    lines = [header] + [",".join(str(row[i]) for i in order) for row in ROWS]
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize(
    "header, order",
    [("t,y0,u0", (0, 1, 2)), ("t,u0,y0", (0, 2, 1)), ("u0,y0", (2, 1)), ("y0,u0", (1, 2))],
)
def test_columns_are_taken_by_name_in_any_order(tmp_path, header, order):
    _, [(y, u)] = read_trajectories(write(tmp_path / "r.csv", header, order))
    np.testing.assert_array_equal(y[:, 0], [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(u[:, 0], [10.0, 20.0, 30.0])


def test_multi_channel_columns_in_any_order(tmp_path):
    path = tmp_path / "r.csv"
    path.write_text("trajectory,t,u1,y1,u0,y0\na,0,4,3,2,1\na,1,8,7,6,5\n")
    _, [(y, u)] = read_trajectories(path)
    np.testing.assert_array_equal(y, [[1, 3], [5, 7]])
    np.testing.assert_array_equal(u, [[2, 4], [6, 8]])


@pytest.mark.parametrize(
    "header, words",
    [
        ("t,y0,y0", "'y0' appears twice"),
        ("t,y1,u0", "no y0"),
        ("t,y0,u1", "no u0"),
        ("t,y0,u0,u2", "no u1"),
        ("t,y0,x0", "'x0' of header 't,y0,x0'"),
        ("t,u0", "no output column"),
    ],
)
def test_a_bad_header_is_one_line_naming_the_column(tmp_path, header, words):
    order = (0, 1, 2, 2)[: len(header.split(","))]
    with pytest.raises(MopError, match=words) as e:
        read_trajectories(write(tmp_path / "r.csv", header, order))
    assert "\n" not in str(e.value) and "trajectory," not in str(e.value)


def test_swapped_columns_fit_the_same_arx_as_the_usual_order(tmp_path, capsys):
    """`mop fit arx` on `t,u0,y0` equals the fit on `t,y0,u0` (it read u as y before)."""
    rng = np.random.default_rng(0)
    u = rng.normal(size=400)
    y = np.zeros(400)
    for t in range(1, 400):
        y[t] = 0.8 * y[t - 1] + u[t - 1] + 0.01 * rng.normal()
    usual, swapped = tmp_path / "usual.csv", tmp_path / "swapped.csv"
    usual.write_text("t,y0,u0\n" + "\n".join(f"{t},{y[t]:.17g},{u[t]:.17g}" for t in range(400)) + "\n")
    swapped.write_text("t,u0,y0\n" + "\n".join(f"{t},{u[t]:.17g},{y[t]:.17g}" for t in range(400)) + "\n")
    assert main(["fit", "arx", str(usual), "--out", str(tmp_path / "a")]) == 0
    assert main(["fit", "arx", str(swapped), "--out", str(tmp_path / "b")]) == 0
    a = (tmp_path / "a" / "fitted.json").read_text().replace("usual", "X")
    b = (tmp_path / "b" / "fitted.json").read_text().replace("swapped", "X")
    assert a == b


def test_large_units_load_and_garbage_is_refused(tmp_path):
    path = tmp_path / "r.csv"
    path.write_text("y0,u0\n2.5e7,1\n2.6e7,2\n")  # encoder counts
    _, [(y, _)] = read_trajectories(path)
    assert y[0, 0] == 2.5e7
    path.write_text("y0,u0\n1e300,1\n2,2\n")
    with pytest.raises(MopError, match="garbled"):
        read_trajectories(path)


def test_an_infinite_input_is_not_called_a_missing_output(tmp_path):
    path = tmp_path / "r.csv"
    path.write_text("y0,u0\n1,inf\n2,2\n")
    with pytest.raises(MopError, match="column u0: the input 'inf' is infinite") as e:
        read_trajectories(path)
    assert "missing output" not in str(e.value)
