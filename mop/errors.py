"""One exception type for every user-facing problem.

Raise :class:`MopError` with a one-line message that names the problem and says what to do.
The CLI prints it as ``mop: error: <message>`` and exits with status 2, without a traceback.
"""


class MopError(Exception):
    """A problem the user can fix (bad input, bad config, missing file)."""
