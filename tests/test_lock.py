"""mop.train.lock: one process trains a run directory; a second waits and reuses it, or is told who."""

import json
import os
import signal
import subprocess
import sys

import pytest

from mop.errors import MopError
from mop.train.lock import run_lock

TINY = [
    "train.steps=4",
    "train.batch_size=4",
    "train.horizon=8",
    "train.log_every=1",
    "train.checkpoint_every=2",
    "train.device=cpu",
    "model.num_layers=1",
    "model.width=16",
    "model.num_heads=2",
    "model.context=8",
]
ENV = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def _train(out, *extra):
    return subprocess.Popen(
        [sys.executable, "-m", "mop", "train", "--out", str(out), "--no-progress", *extra, *TINY],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=ENV,
    )


def test_second_lock_in_the_same_directory_is_refused_naming_the_holder(tmp_path):
    with run_lock(tmp_path), pytest.raises(MopError, match=f"being trained by process {os.getpid()} on"):
        with run_lock(tmp_path, wait=False):
            pass
    with run_lock(tmp_path, wait=False):  # released: free again
        pass


def test_a_waiting_process_trains_once_the_holder_is_gone(tmp_path):
    """The child finds the lock held, says so in one line, waits, then trains; records appear once."""
    out = tmp_path / "run"
    with run_lock(out):
        child = _train(out)
        line = child.stderr.readline()  # blocks until the child reports that it waits
        assert f"is being trained by process {os.getpid()}" in line and "waiting" in line, line
        assert not (out / "config.json").exists()  # it has not started while we hold the lock
    _, err = child.communicate(timeout=300)
    assert child.returncode == 0, err
    steps = [json.loads(r)["step"] for r in (out / "metrics.jsonl").read_text().splitlines()]
    assert steps == [1, 2, 2, 3, 4, 4]  # train record per step, val record per checkpoint, each once
    assert (out / "done.json").exists()


def test_no_wait_says_who_trains_it(tmp_path, capsys):
    from mop.cli import main

    out = tmp_path / "run"
    with run_lock(out):  # flock locks per open file: a second open in this process conflicts like a process
        assert main(["train", "--out", str(out), "--no-progress", "--no-wait", *TINY]) == 2
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    assert f"being trained by process {os.getpid()}" in err and "another --out" in err
    assert not (out / "config.json").exists()


def test_the_lock_of_a_killed_process_is_free(tmp_path):
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, time; from mop.train.lock import run_lock\n"
            f"with run_lock({str(tmp_path)!r}):\n    print('locked', flush=True); time.sleep(600)",
        ],
        stdout=subprocess.PIPE,
        text=True,
        env=ENV,
    )
    assert holder.stdout.readline().strip() == "locked"
    with pytest.raises(MopError, match=f"process {holder.pid}"):
        with run_lock(tmp_path, wait=False):
            pass
    holder.send_signal(signal.SIGKILL)
    holder.wait()
    with run_lock(tmp_path, wait=False):  # the kernel released it: no stale lock
        pass
