"""An advisory lock per run directory, so two processes never train the same run at once.

    with run_lock(out_dir, wait=True):    # a second process waits here, then finds the run finished
        ...

The lock is fcntl.flock on RUN/.lock, which the kernel releases when its process ends however it ends
(SIGKILL included), so a lock is never stale; the file also records the holder (pid, host, start time) for
the message a waiting process prints. Experiments share run directories by config hash, so two
`mop reproduce` in parallel meet here: the second waits and reuses the first one's run. On a system
without fcntl (Windows) the lock is a no-op.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

from mop.atomic import file_mode
from mop.errors import MopError

try:
    import fcntl
except ImportError:  # Windows
    fcntl = None

POLL_SECONDS = 0.2


def _notify(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def holder(path: Path) -> str:
    """Who holds the lock file `path`, in words (from what it recorded)."""
    try:
        info = json.loads(path.read_text())
        since = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(info["since"]))
        return f"process {info['pid']} on {info['host']} (since {since})"
    except (OSError, ValueError, KeyError, TypeError):
        return "another process"


def _try_lock(fd: int) -> bool:
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    return True


@contextlib.contextmanager
def run_lock(
    out_dir: str | os.PathLike, wait: bool = True, notify: Callable[[str], None] = _notify
) -> Iterator[None]:
    """Hold the exclusive lock of run directory `out_dir` (created if missing).

    wait: block until the holder is done (saying so once through `notify`); False raises a one-line
    MopError naming the holder instead.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    if fcntl is None:
        yield
        return
    path = out_dir / ".lock"
    fd = os.open(path, os.O_RDWR | os.O_CREAT, file_mode())
    try:
        if not _try_lock(fd):
            who = holder(path)
            if not wait:
                raise MopError(
                    f"{out_dir} is being trained by {who}; wait for it to finish (the finished run is then "
                    f"reused) or train into another --out"
                )
            notify(f"mop: {out_dir} is being trained by {who}; waiting for it to finish")
            while not _try_lock(fd):
                time.sleep(POLL_SECONDS)
        record = {"pid": os.getpid(), "host": socket.gethostname(), "since": time.time()}
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(record).encode(), 0)
        yield
    finally:
        os.close(fd)  # releases the lock
