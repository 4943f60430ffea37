"""One exception type for every user-facing problem.

Raise :class:`MopError` with a one-line message that names the problem and says what to do.
The CLI prints it as ``mop: error: <message>`` and exits with status 2, without a traceback.
"""


class MopError(Exception):
    """A problem the user can fix (bad input, bad config, missing file)."""


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
