"""One exception type for every user-facing problem.

Raise :class:`MopError` with a one-line message that names the problem and says what to do.
The CLI prints it as ``mop: error: <message>`` and exits with status 2, without a traceback.
A caller that acts on one kind of problem catches its subclass (e.g. NoPretrainedModel), never the text.
"""

import errno
import os
from typing import Any


class MopError(Exception):
    """A problem the user can fix (bad input, bad config, missing file)."""


class NoPretrainedModel(MopError):
    """No shipped pretrained model fits the request (no such name, or none trained on a condition's family);
    `mop reproduce all --pretrained` skips the experiments that raise it."""


class MopWarning(UserWarning):
    """Something the user should know that does not stop the work (the CLI prints it on one line)."""


def os_error_message(err: OSError) -> str:
    """One line for an OSError from reading or writing files: the path, the cause and what to do."""
    path = err.filename if err.filename is not None else "a file"
    code = err.errno
    if code == errno.ENOSPC:
        return f"no space left on the device writing {path}; free some space or write elsewhere (--out)"
    if code == getattr(errno, "EDQUOT", -1):
        return f"disk quota exceeded writing {path}; free some space or write elsewhere (--out)"
    if code in (errno.EACCES, errno.EPERM):
        return f"permission denied: {path}; fix its permissions or use a directory you can write (--out)"
    if code == errno.EROFS:
        return f"{path} is on a read-only file system; write elsewhere (--out)"
    if code == errno.ENOENT:
        return f"{path} does not exist"
    reason = err.strerror or (os.strerror(code) if code else type(err).__name__)
    return f"{reason}: {path}"


def memory_error_message(err: BaseException) -> str:
    """One line for an allocation that failed (MemoryError, torch's out-of-memory RuntimeError)."""
    first = (str(err).splitlines() or [""])[0][:160]
    detail = f" ({first})" if first else ""
    return (
        f"out of memory{detail}; make the job smaller (fewer systems, a shorter horizon or fewer --steps) "
        f"or run it where more memory is free"
    )


def is_out_of_memory(err: BaseException) -> bool:
    """MemoryError, or a RuntimeError from torch's allocators that says it ran out of memory."""
    if isinstance(err, MemoryError):
        return True
    text = str(err)
    return isinstance(err, RuntimeError) and (
        "out of memory" in text or "can't allocate memory" in text or "DefaultCPUAllocator" in text
    )


def require(module: str, purpose: str, extra: str = "bench") -> None:
    """Raise MopError unless the optional dependency `module` imports (e.g. filterpy for the benchmarks)."""
    import importlib

    try:
        importlib.import_module(module)
    except ImportError:
        raise MopError(
            f"{purpose} needs {module}, which is not installed; run: pip install 'mop[{extra}]'"
        ) from None


def check(condition: bool, message: str) -> None:
    """Raise MopError(message) unless condition holds; for __post_init__ validation."""
    if not condition:
        raise MopError(message)


def check_int(where: str, value: Any, low: int, high: int | None = None, note: str = "") -> None:
    """MopError unless `value` is an integer (not a bool) in low..high (high None: no upper bound)."""
    ok = isinstance(value, int) and not isinstance(value, bool) and low <= value
    if high is not None:
        ok, want = ok and value <= high, f"an integer in {low}..{high}"
    else:
        want = "a positive integer" if low == 1 else f"an integer >= {low}"
    check(ok, f"{where} must be {want}{note}, got {value!r}")


def check_choice(where: str, value: Any, choices: tuple[Any, ...]) -> None:
    """MopError unless `value` is one of `choices` (true / false for (True, False))."""
    words = "true or false" if choices == (True, False) else " or ".join(map(repr, choices))
    ok = any(value is c if isinstance(c, bool) else value == c for c in choices)
    check(ok, f"{where} must be {words}, got {value!r}")
