"""`mop train --max-minutes` (issue #66, B): on time the run checkpoints and stops cleanly at the step that
reached the limit, says so and how to resume; it stays usable (mop.load / `mop predict`, warning that it is
unfinished) and the same command resumes it to the weights of a run never stopped, bit for bit. The clock is
a fake one (mop.train.loop.clock) that advances one second each time it is read, so the stop falls on a
known step whatever the machine's speed."""

import itertools
import warnings

import pytest
import torch

import mop
import mop.recipe.fit as recipe_fit
import mop.train.loop as loop
from mop.cli import main
from mop.errors import MopError, MopWarning
from mop.recipe.selection import SELECTION_FILE
from mop.train import train
from mop.train.records import TrainingRecords
from tests.test_budget_selection import arx_plant
from tests.test_train import tiny_config, weights

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture
def fake_clock(monkeypatch):
    """Every read of the training clock advances it by one second, from 0."""
    ticks = itertools.count()
    clock = lambda: float(next(ticks))  # noqa: E731
    monkeypatch.setattr(loop, "clock", clock)
    monkeypatch.setattr(recipe_fit, "loop_clock", clock)
    return clock


def same_weights(a, b) -> bool:
    wa, wb = weights(a), weights(b)
    return wa.keys() == wb.keys() and all(torch.equal(wa[k], wb[k]) for k in wa)


def test_a_deadline_stops_at_its_step_and_the_run_resumes_bit_for_bit(tmp_path, fake_clock):
    config = tiny_config(steps=8, checkpoint_every=4)
    lines = []
    # the deadline is 4 s after the clock's first read; the loop reads it once as it starts, then once
    # after each step: 2, 3, 4 after steps 1, 2, 3, so step 3 (between checkpoints) is the last
    train(config, tmp_path / "run", progress=False, announce=lines.append, deadline=fake_clock() + 4)
    assert "time limit: stopped at step 3 of 8" in lines[-1] and "run the same command to resume" in lines[-1]
    assert not (tmp_path / "run" / "done.json").exists()
    with pytest.warns(MopWarning, match="unfinished: trained to step 3 of 8"):
        mop.load(tmp_path / "run")
    lines.clear()
    train(config, tmp_path / "run", progress=False, announce=lines.append)
    assert "resuming at step 3 of 8" in lines[0]
    train(config, tmp_path / "ref", progress=False)
    assert same_weights(tmp_path / "run", tmp_path / "ref")


def test_mop_train_max_minutes_stops_resumes_and_predicts(tmp_path, fake_clock, capsys):
    rec = tmp_path / "rec.csv"
    arx_plant(rec, steps=700)
    argv = ["train", "--data", str(rec), "--quiet", "train.steps=12", "train.checkpoint_every=5"]
    # 0.05 min = 3 s: the deadline is read 0 + 3; the loop reads 1 as it starts, then 2, 3 after steps 1, 2
    assert main([*argv, "--out", str(tmp_path / "run"), "--max-minutes", "0.05"]) == 0
    out = capsys.readouterr().out
    assert "time limit: stopped at step 2 of 12" in out and "held-out check: not yet" in out
    assert not (tmp_path / "run" / SELECTION_FILE).exists()
    assert main(["predict", str(tmp_path / "run"), str(rec), "--out", str(tmp_path / "p.csv")]) == 0
    assert "unfinished: trained to step 2 of 12" in capsys.readouterr().err
    assert main([*argv, "--out", str(tmp_path / "run"), "--max-minutes", "100"]) == 0
    out = capsys.readouterr().out
    assert "resuming at step 2 of 12" in out and "held-out simulation" in out and "time limit" not in out
    assert main([*argv, "--out", str(tmp_path / "ref")]) == 0
    assert same_weights(tmp_path / "run", tmp_path / "ref")
    with warnings.catch_warnings():
        warnings.simplefilter("error", MopWarning)
        mop.load(tmp_path / "run")


@pytest.mark.parametrize("value", ["0", "-1", "nan", "soon"])
def test_a_bad_max_minutes_is_one_line_before_any_work(tmp_path, value, capsys):
    rec = tmp_path / "rec.csv"
    arx_plant(rec, steps=700)
    with pytest.raises(MopError, match="--max-minutes must be a"):
        recipe_fit.fit_record(tmp_path / "run", TrainingRecords.read(rec), max_minutes=value)
    assert main(["train", "--data", str(rec), "--out", str(tmp_path / "run"), "--max-minutes", value]) != 0
    err = capsys.readouterr().err
    assert "--max-minutes must be a" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "run").exists()
