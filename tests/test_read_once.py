"""`mop train --data FILE` parses FILE once (the CSV reader's calls counted), from scratch with the records
recipe and as a fine-tune whose recipe looks at the record several times (orders, moments, the correction's
gain), and trains the same weights as when every step read the file itself."""

import numpy as np
import pytest

import mop.io
from mop.cli import main
from mop.recipe.layers import training_config
from mop.recipe.selection import select_against_linear
from mop.recipe.training import train
from mop.record import Record, write_records
from mop.train.records import recorded_data

TINY = [
    *("model.num_layers=1", "model.width=16", "model.num_heads=2", "model.context=8"),
    *("train.horizon=8", "train.batch_size=8", "train.steps=3"),
]


@pytest.fixture
def counted(monkeypatch):
    """The number of calls to mop.io.read_csv_timed (the CSV parser) so far."""
    calls = []
    parse = mop.io.read_csv_timed
    monkeypatch.setattr(mop.io, "read_csv_timed", lambda path: calls.append(path) or parse(path))
    return calls


def record_csv(path):
    rng = np.random.default_rng(0)
    u = rng.normal(size=(300, 1))
    y = np.zeros((300, 1))
    for t in range(2, 300):
        y[t] = 1.5 * y[t - 1] - 0.7 * y[t - 2] + 0.3 * u[t - 1] + 0.02 * rng.normal()
    return str(write_records([Record(y=y, u=u, name="r")], path))


def test_train_data_reads_the_file_once(tmp_path, counted, capsys):
    data = record_csv(tmp_path / "rec.csv")
    assert main(["train", "--data", data, "--out", str(tmp_path / "run"), "--no-progress", *TINY]) == 0
    assert "ARX(" in capsys.readouterr().out  # the records recipe looked at the record (its orders)
    assert len(counted) == 1


def test_a_fine_tune_reads_the_file_once_and_trains_the_same_weights(tmp_path, counted, capsys):
    data = record_csv(tmp_path / "rec.csv")
    argv = ["train", "--data", data, "--init", "pretrained:cascaded-tanks", "--no-progress", "train.steps=2"]
    assert main([*argv, "--out", str(tmp_path / "once")]) == 0
    assert "held-out simulation" in capsys.readouterr().out  # the held-out tail at five gains and the ARX
    assert len(counted) == 1
    # each step handed the path alone (no records in memory) reads the file itself
    config = training_config(None, data=data, init="pretrained:cascaded-tanks", overrides=["train.steps=2"])
    each_run = train(config, tmp_path / "each", progress=False)
    select_against_linear(each_run, config, recorded_data(config.data))
    assert len(counted) >= 3
    once, each = ((tmp_path / d / "model.safetensors").read_bytes() for d in ("once", "each"))
    assert once == each


def test_reading_once_hands_out_copies_and_rereads_a_changed_file(tmp_path, counted):
    path = tmp_path / "r.csv"
    write_records([Record(y=np.arange(5.0), name="r")], path)
    with mop.io.reading_once():
        _, [(y, _)] = mop.io.read_trajectories(path)
        y[:] = -1
        _, [(again, _)] = mop.io.read_trajectories(path)
        np.testing.assert_array_equal(again[:, 0], np.arange(5.0))
        assert len(counted) == 1
        write_records([Record(y=np.arange(6.0), name="r")], path)
        assert len(mop.io.read_trajectories(path)[1][0][0]) == 6 and len(counted) == 2
    mop.io.read_trajectories(path)
    assert len(counted) == 3  # outside a block every call reads
