"""A run trained on a plugin's family records the plugin (mop.plugins.PLUGINS_FILE), so a new process loads
and predicts with it (`mop predict`) as the training process does; a plugin file gone, or a run without the
record, is a one-line error that says what to do, not "damaged"."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mop.cli import main
from mop.errors import MopError
from mop.plugins import PLUGINS_FILE
from mop.runs import load_config

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def write_record(path: Path, steps: int = 30) -> None:
    rng = np.random.default_rng(0)
    rows = [f"{t},{y:.6f},{u:.6f}" for t, (y, u) in enumerate(rng.normal(size=(steps, 2)))]
    path.write_text("t,y0,u0\n" + "\n".join(rows) + "\n")


@pytest.fixture(scope="module")
def plugin_run(tmp_path_factory):
    run = tmp_path_factory.mktemp("plugin") / "run"
    toml = EXAMPLES / "dead_time.toml"
    assert main(["train", str(toml), "--preset", "smoke", "--out", str(run), "train.steps=2"]) == 0
    return run


def test_the_run_records_its_plugin_and_a_new_process_predicts_as_this_one(plugin_run, tmp_path):
    assert json.loads((plugin_run / PLUGINS_FILE).read_text()) == [str((EXAMPLES / "dead_time.py").resolve())]
    record = tmp_path / "rec.csv"
    write_record(record)
    here, there = tmp_path / "here.csv", tmp_path / "there.csv"
    assert main(["predict", str(plugin_run), str(record), "--out", str(here)]) == 0
    argv = [sys.executable, "-m", "mop", "predict", str(plugin_run), str(record), "--out", str(there)]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert here.read_text() == there.read_text()


def test_a_plugin_gone_or_not_recorded_is_a_one_line_error(plugin_run, tmp_path):
    moved = tmp_path / "run"
    shutil.copytree(plugin_run, moved)
    (moved / PLUGINS_FILE).write_text(json.dumps([str(tmp_path / "gone.py")]))
    with pytest.raises(MopError, match="gone.py, which is not there any more; put the file back"):
        load_config(moved)
    (moved / PLUGINS_FILE).unlink()
    write_record(tmp_path / "rec.csv")
    argv = [sys.executable, "-m", "mop", "predict", str(moved), str(tmp_path / "rec.csv")]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=300)
    assert done.returncode != 0 and "Traceback" not in done.stderr
    assert "'dead-time', which is not registered here" in done.stderr and "damaged" not in done.stderr
