import json
from pathlib import Path

import pytest

from mop.atomic import atomic_path, write_json

ROOT = Path(__file__).resolve().parents[1]  # the child imports this checkout of mop


def test_failed_write_keeps_previous_file(tmp_path):
    target = tmp_path / "report.json"
    write_json(target, {"version": 1})
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half of a new fi")
        raise RuntimeError("crash mid-write")
    assert json.loads(target.read_text()) == {"version": 1}
    assert list(tmp_path.iterdir()) == [target]  # no temporary left behind


def test_successful_write_replaces(tmp_path):
    target = tmp_path / "sub" / "a.json"
    write_json(target, [1])
    write_json(target, [2])
    assert json.loads(target.read_text()) == [2]


def _dead_pid() -> int:
    import subprocess
    import sys

    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


@pytest.mark.parametrize("umask", [0o022, 0o077, 0o002])
def test_modes_follow_the_umask(umask, tmp_path):
    import os
    import stat

    old = os.umask(umask)
    try:
        write_json(tmp_path / "a.json", [1])
        with open(tmp_path / "plain", "w"):  # what open() gives: the reference
            pass
    finally:
        os.umask(old)
    mode = stat.S_IMODE((tmp_path / "a.json").stat().st_mode)
    assert mode == 0o666 & ~umask == stat.S_IMODE((tmp_path / "plain").stat().st_mode)


def test_orphans_of_dead_processes_are_removed(tmp_path):
    import os

    dead, alive = _dead_pid(), os.getppid()
    orphan = tmp_path / f".checkpoint.safetensors.{dead}.k2j3.tmp.safetensors"
    busy = tmp_path / f".checkpoint.safetensors.{alive}.x9q1.tmp.safetensors"  # a live writer's
    other = tmp_path / f".eval.json.{dead}.ab12.tmp.json"
    for path in (orphan, busy, other):
        path.write_bytes(b"\0" * 100)
    write_json(tmp_path / "checkpoint.safetensors", {})  # a write of that name cleans its orphans
    assert not orphan.exists() and busy.exists() and other.exists()
    from mop.atomic import clean_orphans

    assert clean_orphans(tmp_path) == [other]  # all names: only the dead process's temporaries
    assert busy.exists()


def test_full_disk_keeps_the_previous_file_and_no_temporary(tmp_path, monkeypatch):
    import errno
    import os

    import mop.atomic

    target = tmp_path / "eval.json"
    write_json(target, {"version": 1})

    def full(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(mop.atomic.os, "fsync", full)
    with pytest.raises(OSError) as err:
        write_json(target, {"version": 2})
    assert err.value.errno == errno.ENOSPC and err.value.filename == str(target)  # names the destination
    assert json.loads(target.read_text()) == {"version": 1}
    assert list(tmp_path.iterdir()) == [target]


def test_a_reader_of_the_old_file_keeps_the_whole_old_file(tmp_path):
    """The new file is moved over the old one (a new file under the name), never written into it: a reader
    that opened the old file before the write still reads all of it afterwards, and never a mix."""
    target = tmp_path / "eval.json"
    old = {"version": 1, "payload": "x" * 100_000}
    write_json(target, old)
    with open(target) as reader:
        first = reader.read(10)
        write_json(target, {"version": 2, "payload": "y" * 50})
        assert json.loads(first + reader.read()) == old
    assert json.loads(target.read_text())["version"] == 2


KILLED_MID_WRITE = """
import os, signal, sys
from mop.atomic import atomic_write
def write(tmp):
    with open(tmp, "w") as f:
        f.write('{"version": 2, "payload": "')
        f.flush()
        os.kill(os.getpid(), signal.SIGKILL)  # killed half-way through writing the new file
atomic_write(sys.argv[1], write)
"""


def test_a_process_killed_mid_write_leaves_the_old_file_whole(tmp_path):
    """A real SIGKILL while the new contents are written: the destination is still the old file, whole;
    the dead process's temporary is removed by the next write of that name."""
    import subprocess
    import sys

    target = tmp_path / "eval.json"
    write_json(target, {"version": 1})
    child = subprocess.run(
        [sys.executable, "-c", KILLED_MID_WRITE, str(target)], capture_output=True, cwd=ROOT
    )
    assert child.returncode == -9, child.stderr
    assert json.loads(target.read_text()) == {"version": 1}
    (orphan,) = [p for p in tmp_path.iterdir() if p != target]
    write_json(target, {"version": 3})
    assert not orphan.exists() and json.loads(target.read_text()) == {"version": 3}
