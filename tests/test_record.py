"""mop.record.Record: the shapes it takes, slicing, the split's rounding, and reading a file once."""

import numpy as np
import pytest

from mop.errors import MopError
from mop.io import read_trajectories
from mop.record import Record, as_pairs, read_records


def _record(T=10, m=2, k=1, **kw):
    rng = np.random.default_rng(0)
    return Record(y=rng.normal(size=(T, m)), u=rng.normal(size=(T, k)), **kw)


def test_one_dimensional_arrays_are_one_channel():
    r = Record(y=np.arange(5.0), u=np.ones(5), sampling_time=0.1, name="a")
    assert r.y.shape == (5, 1) and r.u.shape == (5, 1)
    assert (r.num_outputs, r.num_inputs, len(r)) == (1, 1, 5)


def test_slicing_is_in_time_and_keeps_the_fields():
    r = _record(T=10, sampling_time=0.5, name="x", init_window=3)
    s = r[2:7]
    np.testing.assert_array_equal(s.y, r.y[2:7])
    np.testing.assert_array_equal(s.u, r.u[2:7])
    assert (s.name, s.sampling_time, s.init_window) == ("x", 0.5, 3)
    assert r[:2].init_window == 2


@pytest.mark.parametrize("T, fraction, tail", [(10, 0.25, 3), (11, 0.1, 2), (100, 0.2, 20)])
def test_split_rounds_the_held_out_part_up(T, fraction, tail):
    head, last = _record(T=T).split(fraction)
    assert len(last) == tail and len(head) + len(last) == T


@pytest.mark.parametrize(
    "kw, words",
    [
        (dict(y=np.zeros((4, 1)), u=np.zeros((3, 1))), "sampled together"),
        (dict(y=np.zeros((2, 2, 2))), "shape"),
        (dict(y=np.zeros(4), u=np.array([0, np.nan, 0, 0])), "inputs must be complete"),
        (dict(y=np.array([0, np.inf])), "Inf"),
        (dict(y=np.zeros(4), sampling_time=0.0), "sampling_time"),
        (dict(y=np.zeros(4), init_window=5), "init_window"),
    ],
)
def test_bad_arrays_are_one_line(kw, words):
    with pytest.raises(MopError, match=words):
        Record(**kw)


def test_read_records_equals_read_trajectories(tmp_path):
    p = tmp_path / "rec.csv"
    p.write_text("t,y0,u0\n0,1.0,0.5\n1,,0.25\n2,3.0,0.0\n")
    (r,) = read_records(p, sampling_time=0.01)
    names, data = read_trajectories(p)
    assert r.name == names[0] == "rec" and r.sampling_time == 0.01
    ((y, u),) = as_pairs([r])
    np.testing.assert_array_equal(y, data[0][0])
    np.testing.assert_array_equal(u, data[0][1])
    assert np.isnan(r.y[1, 0])
