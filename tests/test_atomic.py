import json

import pytest

from mop.atomic import atomic_path, write_json


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
