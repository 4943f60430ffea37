"""A record with a gap keeps the records recipe off (its least-squares feature needs complete outputs):
`mop train --data REC model.observation_mask=true` says so and what it trains instead, and refuses a
--budget it would not plan, in one line before any work (issue #66, B)."""

import pytest

from mop.cli import main
from tests.test_budget_selection import arx_plant

pytestmark = pytest.mark.usefixtures("one_thread")


def record_with_a_gap(path):
    arx_plant(path, steps=700)
    lines = path.read_text().splitlines()
    lines[300] = "," + lines[300].split(",")[1]  # one missing output
    path.write_text("\n".join(lines) + "\n")
    return str(path)


def test_a_budget_on_a_record_with_a_gap_is_refused_in_one_line(tmp_path, capsys):
    rec = record_with_a_gap(tmp_path / "rec.csv")
    argv = ["train", "--data", rec, "--out", str(tmp_path / "run"), "model.observation_mask=true"]
    assert main([*argv, "--budget", "1"]) != 0
    err = capsys.readouterr().err
    assert "--budget plans the records recipe" in err and "1 missing output(s)" in err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "run").exists()


def test_the_run_says_the_records_recipe_is_off_and_what_it_trains(tmp_path, capsys):
    rec = record_with_a_gap(tmp_path / "rec.csv")
    argv = ["train", "--data", rec, "--out", str(tmp_path / "run"), "--quiet", "model.observation_mask=true"]
    assert main([*argv, "train.steps=2", "model.num_layers=1", "model.width=16"]) == 0
    out = capsys.readouterr().out
    assert "records recipe: off" in out and "1 missing output(s)" in out
    assert "1 x 16 model for 2 steps, with no --budget plan and no held-out check" in out
    assert "held-out simulation" not in out
