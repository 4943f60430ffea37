"""Atomic file writes: a crash mid-write leaves the previous file whole.

Everything is written to a temporary file in the destination's directory, flushed to disk, then moved over the
destination with os.replace (atomic on POSIX and Windows within one file system).

The temporary is named `.<name>.<pid>.<random>.tmp<suffix>`: a process killed mid-write (SIGKILL, power loss)
leaves it behind, and the next write into that directory removes every such file whose process is gone
(`clean_orphans`), so a crashed checkpoint copy does not stay on disk. Files get the mode an ordinary
`open()` would give them (0666 less the umask), not mkstemp's 0600, so a shared run directory stays
readable by colleagues.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import tempfile
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

_ORPHAN = re.compile(r"^\..+\.(\d+)\.[^.]+\.tmp")  # .<name>.<pid>.<random>.tmp<suffix>
_umask_lock = threading.Lock()


def current_umask() -> int:
    """The process umask (read by setting and restoring it; guarded against other threads doing the same)."""
    with _umask_lock:
        mask = os.umask(0o022)
        os.umask(mask)
    return mask


def file_mode() -> int:
    """The mode open() gives a new file: 0666 without the umask's bits."""
    return 0o666 & ~current_umask()


def pid_alive(pid: int) -> bool:
    """Whether process `pid` exists (on this machine); a pid we may not signal still exists."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def clean_orphans(directory: str | os.PathLike, name: str | None = None) -> list[Path]:
    """Remove temporaries (files or staging folders) of dead processes in `directory`; the removed paths.

    name: only temporaries of that destination name (as atomic_path makes them), else all of them.
    Temporaries of live processes (another writer right now) are left alone.
    """
    directory = Path(directory)
    removed = []
    try:
        entries = list(os.scandir(directory))
    except OSError:
        return removed
    prefix = None if name is None else f".{name}."
    for entry in entries:
        match = _ORPHAN.match(entry.name)
        if not match or (prefix and not entry.name.startswith(prefix)):
            continue
        if int(match.group(1)) == os.getpid() or pid_alive(int(match.group(1))):
            continue
        with contextlib.suppress(OSError):
            if entry.is_dir(follow_symlinks=False):
                shutil.rmtree(entry.path)
            else:
                os.unlink(entry.path)
            removed.append(Path(entry.path))
    return removed


def temp_name(path: Path) -> str:
    """The prefix of a temporary for `path`: `.<name>.<pid>.` (clean_orphans recognises it)."""
    return f".{path.name}.{os.getpid()}."


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path next to `path`; on success move it over `path`, on error delete it.

    Use for libraries that write to a filename themselves (np.savez, safetensors.save_file, savefig):
        with atomic_path("out.npz") as tmp:
            np.savez(tmp, ...)
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    clean_orphans(path.parent, path.name)
    fd, tmp_name = tempfile.mkstemp(prefix=temp_name(path), suffix=".tmp" + path.suffix, dir=path.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        os.chmod(tmp, file_mode())
        yield tmp
        with open(tmp, "rb+") as handle:
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except OSError as err:
        if err.filename is None or str(err.filename) == str(tmp):  # name the destination, not the temporary
            raise type(err)(err.errno, err.strerror, str(path)) from None
        raise
    finally:
        tmp.unlink(missing_ok=True)


def atomic_write(path: str | os.PathLike, write: Callable[[Path], Any]) -> None:
    """Call write(tmp_path), then atomically move the result to `path`."""
    with atomic_path(path) as tmp:
        write(tmp)


def write_text(path: str | os.PathLike, text: str) -> None:
    atomic_write(path, lambda tmp: tmp.write_text(text))


def write_json(path: str | os.PathLike, data: Any) -> None:
    write_text(path, json.dumps(data, indent=2, sort_keys=False) + "\n")
