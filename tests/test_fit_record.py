"""One path from a record to a run (mop.recipe.fit.fit_record): `mop train --data FILE` and
mop.estimators.Learned train the same weights, make the same held-out choice and write the same config (less
the record's file name), from scratch with the records recipe and as a fine-tune; `mop train` prints what
fit_record announces (less the
loop's plan line, whose time is measured)."""

import json
import re

import numpy as np
import pytest

from mop.cli import main
from mop.estimators import Learned
from mop.recipe.fit import fit_record
from mop.record import Record, write_records
from mop.train.records import TrainingRecords

TINY = {
    **{"model.num_layers": 1, "model.width": 16, "model.num_heads": 2, "model.context": 8},
    **{"train.horizon": 8, "train.batch_size": 8, "train.steps": 3},
}


def plant(steps=300, seed=0):
    rng = np.random.default_rng(seed)
    u, y = rng.normal(size=(steps, 1)), np.zeros((steps, 1))
    for t in range(2, steps):
        y[t] = 1.5 * y[t - 1] - 0.7 * y[t - 2] + 0.3 * u[t - 1] + 0.02 * rng.normal()
    return Record(y=y, u=u, name="r")


def saved(run):
    """What the path decides in a run directory: its weights, its choice, its config less data.path."""
    config = json.loads((run / "config.json").read_text())
    config["data"].pop("path")
    choice = json.loads((run / "selection.json").read_text())
    return (run / "model.safetensors").read_bytes(), choice, config


@pytest.mark.parametrize(
    "init, overrides",
    [(None, TINY), ("pretrained:cascaded-tanks", {"train.steps": 2})],
    ids=["records-recipe", "fine-tune"],
)
def test_mop_train_data_and_learned_train_the_same_run(tmp_path, capsys, init, overrides):
    record = plant()
    data = str(write_records([record], tmp_path / "rec.csv"))
    argv = ["train", "--data", data, "--out", str(tmp_path / "cli"), "--no-progress"]
    argv += [*(["--init", init] if init else []), *(f"{k}={v}" for k, v in overrides.items())]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    learned = Learned(init=init, out_dir=tmp_path / "learned", **overrides).fit(record)
    assert learned.selection_ is not None  # both make the held-out choice, the fine-tune too
    assert saved(learned.run_dir_) == saved(tmp_path / "cli")
    assert learned.selection_ == json.loads((tmp_path / "cli" / "selection.json").read_text())
    assert "held-out simulation" in printed


def test_mop_train_prints_what_fit_record_announces(tmp_path, capsys):
    data = str(write_records([plant()], tmp_path / "rec.csv"))
    overrides = [f"{k}={v}" for k, v in TINY.items()]
    assert main(["train", "--data", data, "--out", str(tmp_path / "cli"), "--no-progress", *overrides]) == 0
    printed = capsys.readouterr().out.splitlines()
    lines: list[str] = []
    records = TrainingRecords.read(data)  # read at the edge, as `mop train` reads it
    run = fit_record(tmp_path / "py", records, overrides=overrides, progress=False, announce=lines.append)
    timed = lambda out: [line.startswith("model: ") for line in out]  # noqa: E731  (the loop's timed plan)
    assert timed(printed[:-1]) == timed(lines) and sum(timed(lines)) == 1
    # the loop's plan line is timed, and so is the training time the held-out check's line names
    clock = lambda line: re.sub(r"about [^)]* of training", "about T of training", line)  # noqa: E731
    untimed = lambda out: [clock(line) for line in out if not line.startswith("model: ")]  # noqa: E731
    assert untimed(printed[:-1]) == untimed(lines)  # the command adds the run directory's line
    assert printed[-1].startswith(f"run directory: {tmp_path / 'cli'}")
    assert run.selection == json.loads((run.run_dir / "selection.json").read_text())
    assert any(line.startswith("data ") for line in lines) and lines[-1].startswith("held-out check")
