"""Progress for a terminal or a log: a tqdm bar on a TTY, otherwise a plain line every few seconds.

    bar = progress(total=2500, desc="train")        # initial=step when resuming
    for step in ...:
        bar.update(1)
        bar.set_postfix(loss=f"{loss:.4g}")         # shown with the next line (or on the bar)
    bar.close()                                      # prints the final line

A log line: `train: step 1200/2500 (48%), 7.1 steps/s, ETA 3m03s, loss=0.2531`. Lines are printed at most
every `interval` seconds (default 10) plus one at close, so a long run writes a few hundred lines, not the
megabytes of carriage-return redraws tqdm writes into a file. `progress(..., disable=True)` does nothing.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO


def progress(
    total: int | None,
    desc: str = "",
    *,
    initial: int = 0,
    interval: float = 10.0,
    file: TextIO | None = None,
    disable: bool = False,
):
    """A tqdm bar if `file` (default stderr) is a terminal, else a LogProgress (update/set_postfix/close)."""
    file = file if file is not None else sys.stderr
    if disable:
        return LogProgress(total, desc, initial=initial, interval=interval, file=file, disable=True)
    if _isatty(file):
        from tqdm import tqdm

        return tqdm(total=total, desc=desc, initial=initial, file=file, dynamic_ncols=True)
    return LogProgress(total, desc, initial=initial, interval=interval, file=file)


def _isatty(file: TextIO) -> bool:
    try:
        return file.isatty()
    except (AttributeError, ValueError):
        return False


class LogProgress:
    """Plain progress lines (step, rate, ETA, postfix) at most every `interval` seconds, one at close()."""

    def __init__(
        self,
        total: int | None,
        desc: str = "",
        *,
        initial: int = 0,
        interval: float = 10.0,
        file: TextIO | None = None,
        disable: bool = False,
    ) -> None:
        self.total, self.desc, self.n, self.interval = total, desc, initial, interval
        self.file = file if file is not None else sys.stderr
        self.disable, self.closed = disable, False
        self.postfix: dict[str, object] = {}
        self.start = self.last = time.monotonic()
        self.start_n = initial

    def update(self, n: int = 1) -> None:
        self.n += n
        now = time.monotonic()
        if now - self.last >= self.interval:
            self.last = now
            self._print(now)

    def set_postfix(self, ordered_dict: dict | None = None, **kwargs) -> None:
        self.postfix = {**(ordered_dict or {}), **kwargs}

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self._print(time.monotonic())

    def __enter__(self) -> LogProgress:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def line(self, now: float | None = None) -> str:
        now = time.monotonic() if now is None else now
        elapsed = now - self.start
        rate = (self.n - self.start_n) / elapsed if elapsed > 0 else 0.0
        parts = [f"step {self.n}"]
        if self.total:
            parts[0] += f"/{self.total} ({100 * self.n / self.total:.0f}%)"
        parts.append(f"{rate:.1f} steps/s")
        if self.total and rate > 0 and self.n < self.total:
            parts.append(f"ETA {_duration((self.total - self.n) / rate)}")
        elif self.closed:
            parts.append(f"took {_duration(elapsed)}")
        parts += [f"{k}={v}" for k, v in self.postfix.items()]
        return f"{self.desc + ': ' if self.desc else ''}{', '.join(parts)}"

    def _print(self, now: float) -> None:
        if not self.disable:
            print(self.line(now), file=self.file, flush=True)


def _duration(seconds: float) -> str:
    seconds = int(round(seconds))
    h, rest = divmod(seconds, 3600)
    m, s = divmod(rest, 60)
    return f"{h}h{m:02d}m{s:02d}s" if h else f"{m}m{s:02d}s" if m else f"{s}s"
