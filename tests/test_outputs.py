"""mop.outputs: output folders all or nothing, marked complete; and mop reproduce built on it."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from mop.errors import MopError
from mop.outputs import MARKER, is_complete, read_results, staged_output

ROOT = Path(__file__).resolve().parents[1]  # the child imports this checkout of mop


def _write(stage, **files):
    for name, text in files.items():
        (stage / name).write_text(text)


def test_a_stopped_command_leaves_the_previous_folder_whole(tmp_path):
    with staged_output(tmp_path) as stage:
        _write(stage, **{"eval.json": '{"seed": 0}', "fig_a.png": "a0", "report.md": "r0"})
    with pytest.raises(KeyboardInterrupt), staged_output(tmp_path) as stage:
        _write(stage, **{"fig_a.png": "a1"})  # a new figure is written, then the command is stopped
        raise KeyboardInterrupt
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == sorted(["eval.json", "fig_a.png", "report.md", MARKER])
    assert (tmp_path / "fig_a.png").read_text() == "a0" and read_results(tmp_path) == {"seed": 0}


def test_a_finished_command_replaces_every_file_of_the_previous_one(tmp_path):
    with staged_output(tmp_path) as stage:
        _write(stage, **{"eval.json": "{}", "old_fig.png": "x"})
    (tmp_path / "notes.txt").write_text("mine")  # not ours: kept
    with staged_output(tmp_path) as stage:
        _write(stage, **{"eval.json": '{"seed": 1}', "new_fig.png": "y"})
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == sorted(["eval.json", "new_fig.png", "notes.txt", MARKER])
    assert json.loads((tmp_path / MARKER).read_text())["files"] == ["eval.json", "new_fig.png"]


def test_readers_refuse_a_folder_without_the_marker(tmp_path):
    (tmp_path / "eval.json").write_text("{}")
    assert not is_complete(tmp_path)
    with pytest.raises(MopError, match="incomplete"):
        read_results(tmp_path)


def test_the_staging_folder_of_a_killed_command_is_removed_next_time(tmp_path):
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    orphan = tmp_path / f".output.{child.pid}.abc123.tmp"
    orphan.mkdir()
    (orphan / "eval.json").write_text("{}")
    with staged_output(tmp_path) as stage:
        _write(stage, **{"eval.json": "{}"})
    assert not orphan.exists() and is_complete(tmp_path)


def test_compare_evals_refuses_an_incomplete_tree(tmp_path):
    for side in ("a", "b"):
        (tmp_path / side / "linear").mkdir(parents=True)
        (tmp_path / side / "linear" / "eval.json").write_text('{"predictors": {}}')
    (tmp_path / "a" / "linear" / MARKER).write_text('{"files": ["eval.json"]}')
    script = ["scripts/compare_evals.py", str(tmp_path / "a"), str(tmp_path / "b")]
    r = subprocess.run([sys.executable, *script], capture_output=True, text=True)
    assert "linear: incomplete in" in r.stdout, r.stdout + r.stderr


def test_reproduce_on_a_full_disk_then_with_a_damaged_shared_run(tmp_path, tiny_smoke, capsys, monkeypatch):
    """Both end in one line and leave the previous output folder whole, with no temporary or staging left."""
    import errno
    import os

    import mop.atomic
    from mop.cli import main
    from tests.test_checkpoint import _damage

    exp = {"name": "t", "title": "t", "predictors": ["mop", "last"], "reference": "last", "figures": []}
    (tmp_path / "t.json").write_text(json.dumps({**exp, "train": {"system.family": "linear"}}))
    out = tmp_path / "t"
    argv = ["reproduce", str(tmp_path / "t.json"), "--preset", "smoke", "--out", str(out), "--quiet"]
    assert main(argv) == 0
    capsys.readouterr()
    before = (out / "eval.json").read_bytes()
    with monkeypatch.context() as patch:

        def full(fd):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

        patch.setattr(mop.atomic.os, "fsync", full)
        assert main([*argv, "--seed", "0"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no space left on the device writing" in err, err
    assert (out / "eval.json").read_bytes() == before and is_complete(out)
    assert not [p for p in out.iterdir() if p.name.startswith(".")]
    (run,) = json.loads(before)["runs"].values()
    _damage(tmp_path / "runs" / run.split("/")[-1] / "model.safetensors")
    assert main([*argv, "--seed", "0"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "sha256" in err and "--fresh" in err, err
    assert (out / "eval.json").read_bytes() == before and is_complete(out)


def test_the_previous_marker_is_gone_before_any_file_moves(tmp_path, monkeypatch):
    """At every move of a new file into the folder the previous run's marker is already removed, so a
    command stopped between two moves leaves a folder that readers refuse (a failure point is injected at
    the second move)."""
    import os

    import mop.outputs

    with staged_output(tmp_path) as stage:
        _write(stage, **{"eval.json": '{"seed": 0}', "report.md": "r0"})
    seen, real_replace = [], os.replace

    def replace_then_stop(src, dst):
        seen.append((tmp_path / MARKER).exists())
        if len(seen) == 2:
            raise KeyboardInterrupt  # stopped between the first and the second move
        real_replace(src, dst)

    monkeypatch.setattr(mop.outputs.os, "replace", replace_then_stop)
    with pytest.raises(KeyboardInterrupt), staged_output(tmp_path) as stage:
        _write(stage, **{"eval.json": '{"seed": 1}', "fig.png": "f1", "report.md": "r1"})
    assert seen == [False, False]
    assert not is_complete(tmp_path)
    with pytest.raises(MopError, match="incomplete"):
        read_results(tmp_path)


KILLED_MID_MOVE = """
import os, signal, sys
import mop.outputs
from mop.outputs import staged_output
real, calls = os.replace, []
def replace(src, dst):
    calls.append(dst)
    if len(calls) == 2:
        os.kill(os.getpid(), signal.SIGKILL)  # killed between the first and the second move
    real(src, dst)
mop.outputs.os.replace = replace
with staged_output(sys.argv[1]) as stage:
    for name in ("eval.json", "fig.png", "report.md"):
        (stage / name).write_text('{"seed": 1}')
"""


def test_a_process_killed_between_moves_leaves_a_folder_readers_refuse(tmp_path):
    """A real SIGKILL between two moves (no finally, no cleanup): no marker, so read_results refuses the
    half-moved folder; the next run removes the dead process's staging folder and completes."""
    with staged_output(tmp_path) as stage:
        _write(stage, **{"eval.json": '{"seed": 0}', "fig.png": "f0", "report.md": "r0"})
    child = subprocess.run(
        [sys.executable, "-c", KILLED_MID_MOVE, str(tmp_path)], capture_output=True, cwd=ROOT
    )
    assert child.returncode == -9, child.stderr
    assert json.loads((tmp_path / "eval.json").read_text()) == {"seed": 1}  # the first file had moved
    assert (tmp_path / "fig.png").read_text() == "f0" and not is_complete(tmp_path)
    with pytest.raises(MopError, match="incomplete"):
        read_results(tmp_path)
    assert [p for p in tmp_path.iterdir() if p.name.startswith(".output.")]  # its staging folder
    with staged_output(tmp_path) as stage:
        _write(stage, **{"eval.json": '{"seed": 2}'})
    assert read_results(tmp_path) == {"seed": 2}
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
