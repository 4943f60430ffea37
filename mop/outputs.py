"""Output folders written all or nothing, with a completion marker that readers check.

    with staged_output(out) as stage:       # write eval.json, figures, report.md into `stage`
        ...
    data = read_results(out)                # eval.json, or a one-line MopError if `out` is incomplete

The files are written into a staging folder inside `out` (`.output.<pid>.<random>.tmp`). Only when all of
them exist are they moved into `out` (one os.replace each): the marker `complete.json` is removed first,
the previous run's files that this run does not write are deleted, the new ones moved in, and the marker,
listing them, written last. A command killed while computing leaves the previous folder whole and marked
complete (its staging folder is removed on the next run, mop.atomic.clean_orphans); one killed in the
milliseconds of the moves leaves a folder without a marker, which `read_results` refuses.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from mop.atomic import clean_orphans, current_umask, write_json
from mop.errors import MopError

MARKER = "complete.json"


def _previous_files(out: Path) -> set[str]:
    try:
        return set(json.loads((out / MARKER).read_text())["files"])
    except (OSError, ValueError, KeyError, TypeError):
        return set()


@contextlib.contextmanager
def staged_output(out: str | os.PathLike) -> Iterator[Path]:
    """Yield a staging folder; on success move its files into `out` and mark `out` complete."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    clean_orphans(out)
    stage = Path(tempfile.mkdtemp(prefix=f".output.{os.getpid()}.", suffix=".tmp", dir=out))
    try:
        os.chmod(stage, 0o777 & ~current_umask())
        yield stage
        files = sorted(p.name for p in stage.iterdir())
        previous = _previous_files(out)
        (out / MARKER).unlink(missing_ok=True)  # incomplete from here until the new marker
        for name in previous - set(files) - {MARKER}:
            (out / name).unlink(missing_ok=True)
        for name in files:
            os.replace(stage / name, out / name)
        write_json(out / MARKER, {"files": files, "finished": time.strftime("%Y-%m-%dT%H:%M:%S")})
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def is_complete(out: str | os.PathLike) -> bool:
    """Whether `out` holds the whole output of a finished command (its marker is there)."""
    return (Path(out) / MARKER).is_file()


def read_results(out: str | os.PathLike, name: str = "eval.json") -> Any:
    """The JSON file `name` of a complete output folder; MopError if the folder is incomplete."""
    out = Path(out)
    if not is_complete(out):
        raise MopError(
            f"{out} is incomplete (no {MARKER}: the command that wrote it was stopped); run it again"
        )
    try:
        return json.loads((out / name).read_text())
    except (OSError, ValueError) as err:
        raise MopError(f"{out / name} cannot be read ({type(err).__name__}); run the command again") from None
