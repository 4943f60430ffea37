"""A record is read once, at the edge, and flows down in memory (mop.train.records.TrainingRecords): the
records recipe plans from a record in memory (mop.recipe.records.plan_records, a RecordsPlan) as from the
same record written to CSV and read back; `mop train --data FILE` reads FILE once; Learned.fit writes no
file of the records and leaves no temporary folder behind."""

import gc
import tempfile

import numpy as np
import pytest

import mop.record
from mop.cli import main
from mop.config import DataConfig
from mop.errors import MopError
from mop.estimators import Learned
from mop.recipe.layers import records_config, training_config
from mop.recipe.plan import RecordsPlan
from mop.recipe.records import plan_records
from mop.record import Record, read_records, write_records
from mop.train.records import TrainingRecords

TINY = {
    "model__width": 16,
    "model__context": 8,
    "train__horizon": 8,
    "train__batch_size": 8,
    "train__steps": 2,
}
TINY_KEYS = [f"{k.replace('__', '.')}={v}" for k, v in TINY.items()]


def plant(T: int = 400, seed: int = 0, name: str = "r") -> Record:
    """A second-order ARX plant with a mild cubic term, driven by noise."""
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(T, 1))
    y = np.zeros((T, 1))
    for t in range(2, T):
        y[t] = 1.4 * y[t - 1] - 0.6 * y[t - 2] + 0.3 * u[t - 1] - 0.05 * y[t - 1] ** 3 + 0.01 * rng.normal()
    return Record(y=y, u=u, name=name)


@pytest.fixture
def reads(monkeypatch):
    """The paths read_records has read so far (every call goes through mop.record.read_timed)."""
    calls = []
    read = mop.record.read_timed
    monkeypatch.setattr(mop.record, "read_timed", lambda path: calls.append(str(path)) or read(path))
    return calls


def test_the_plan_of_a_record_in_memory_is_the_plan_of_its_file(tmp_path, reads):
    records = [plant(400, 0, "a"), plant(300, 1, "b")]
    config = training_config(None, "small")
    cfg = DataConfig(path="in memory")
    in_memory = plan_records(TrainingRecords(tuple(records)).split(cfg).training_part, config, budget=1.0)
    assert reads == []  # the recipe read nothing from disk
    path = write_records(records, tmp_path / "r.csv")
    from_file = plan_records(TrainingRecords.read(path).split(cfg).training_part, config, budget=1.0)
    assert isinstance(in_memory, RecordsPlan) and in_memory == from_file
    assert in_memory.settings()["model.rls_order"] == in_memory.p > 0 and in_memory.steps >= 1000
    # the whole config: the same but for where the records came from
    memory_config = training_config(None, data=TrainingRecords(tuple(records), source=str(path)))
    assert memory_config == training_config(None, data=str(path))


def test_mop_train_data_reads_the_file_once(tmp_path, reads, capsys):
    path = str(write_records([plant(400, 0)], tmp_path / "r.csv"))
    argv = ["train", "--data", path, "--out", str(tmp_path / "run"), "--quiet", *TINY_KEYS, "model.arch=gpt"]
    assert main(argv) == 0
    assert "orders:" in capsys.readouterr().out  # the recipe planned on the record, then it trained
    assert reads == [path]
    val = str(write_records([plant(200, 3)], tmp_path / "v.csv"))
    reads.clear()
    argv = ["train", "--data", path, "--val", val, "--out", str(tmp_path / "val"), "--quiet", *TINY_KEYS]
    assert main(argv) == 0
    assert reads == [val, path]  # each file once


def test_learned_fit_writes_no_file_of_the_records_and_leaves_no_folder(tmp_path, monkeypatch, reads):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    record = plant(300, 0)
    est = Learned(**TINY).fit(record)
    assert reads == []  # nothing written to be read back
    [folder] = (tmp_path / "tmp").iterdir()
    assert folder.name.startswith("mop-learned-") and sorted(p.name for p in folder.iterdir()) == ["run"]
    y = est.predict(record)
    del est
    gc.collect()
    assert list((tmp_path / "tmp").iterdir()) == []  # removed with the estimator
    again = Learned(out_dir=tmp_path / "out", **TINY).fit(record)
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["run"]
    np.testing.assert_array_equal(again.predict(record), y)  # the same seed, the same weights
    path = write_records([record], tmp_path / "r.csv")
    assert reads == []
    from_file = Learned(out_dir=tmp_path / "file", **TINY).fit(str(path))
    assert reads == [str(path)]  # the user's file is read once, at the edge
    np.testing.assert_array_equal(from_file.predict(read_records(path)[0]), y)


def test_a_record_is_named_once(tmp_path, reads):
    path = str(write_records([plant(300, 0)], tmp_path / "r.csv"))
    other = str(write_records([plant(300, 1)], tmp_path / "o.csv"))
    with pytest.raises(MopError) as e:
        training_config(None, data=path, overrides=[f'data.path="{other}"'])
    assert "name the record once" in str(e.value) and reads == [path]
    # a validation file named by its key validates the run, as --val does (the recipe, before the
    # overrides, planned on the record's own split)
    config, records = records_config(
        None, None, TrainingRecords.read(path), [f'data.validation_path="{other}"']
    )
    assert config.data.validation_path == other and records.split(config.data).split == "file"
