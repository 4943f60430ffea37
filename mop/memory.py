"""Estimates before large allocations: a job that would not fit is refused with the number, in one line.

    check_allocation(nbytes, "mop simulate of 30000 systems x 10001 steps", "simulate fewer systems")

The limit is MOP_MEMORY_LIMIT_GB when set, else 80% of the memory the operating system reports available
now (Linux: MemAvailable of /proc/meminfo; elsewhere the free physical pages; no limit where neither can be
read). The estimates are a stated multiple of the arrays a job must hold at once (each caller documents
its factor), measured on a 2-core AMD EPYC CPU.
"""

from __future__ import annotations

import os

from mop.errors import MopError

LIMIT_ENV = "MOP_MEMORY_LIMIT_GB"
AVAILABLE_FRACTION = 0.8


def available_bytes() -> int | None:
    """Memory available to a new allocation without swapping (bytes), or None where it cannot be read."""
    try:
        with open("/proc/meminfo") as handle:
            for line in handle:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def memory_limit() -> tuple[float, str]:
    """(limit in bytes, where it comes from, in words)."""
    raw = os.environ.get(LIMIT_ENV)
    if raw:
        try:
            return float(raw) * 1e9, f"{LIMIT_ENV}={raw}"
        except ValueError:
            raise MopError(f"{LIMIT_ENV} must be a number of GB, got {raw!r}") from None
    available = available_bytes()
    if available is None:
        return float("inf"), "no limit known"
    return AVAILABLE_FRACTION * available, f"{AVAILABLE_FRACTION:.0%} of the memory available now"


def gigabytes(nbytes: float) -> str:
    gb = nbytes / 1e9
    return f"{gb:,.0f} GB" if gb >= 100 else f"{gb:.3g} GB"


def check_allocation(nbytes: float, what: str, advice: str) -> None:
    """MopError when a job estimated at `nbytes` exceeds the memory limit; `advice` says how to shrink it."""
    limit, source = memory_limit()
    if nbytes > limit:
        raise MopError(
            f"{what} needs about {gigabytes(nbytes)} of memory, above the limit of {gigabytes(limit)} "
            f"({source}; set {LIMIT_ENV} to change it); {advice}"
        )
