"""A measured input-output record: the type a user's data, a benchmark's split and an identifier all share.

It has the shape of the identification field's `Input_output_data` (the official `nonlinear_benchmarks`
loader, deepSI): outputs y (T, m) and inputs u (T, k) sampled at the same instants, a sampling time, a name,
and the length of the state-initialization window (the first `init_window` outputs a simulation may read
before it runs from the inputs alone). Slicing with a time slice gives a record of those steps.

Time index t runs 0..T-1 (T = len(record)); y[t] and u[t] are measured at the same instant t * sampling_time.
Missing outputs are NaN in y; inputs must be complete.
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import math
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from mop.atomic import atomic_path
from mop.errors import MopError
from mop.io import read_timed

Pair = tuple[np.ndarray, np.ndarray | None]  # (y (T, m), u (T, k) | None): the arrays mop's functions take


def _as_2d(name: str, a: np.ndarray | Sequence[float], where: str) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim != 2:
        raise MopError(f"{where}: {name} has shape {a.shape}; give (T,) or (T, channels)")
    return a


@dataclasses.dataclass(frozen=True, eq=False)
class Record:
    """One record: y (T, m) and u (T, k) or None, at `sampling_time` seconds (None: not known).

    `init_window`: how many first outputs initialize a simulation of this record (the benchmark's
    state_initialization_window_length; 0 where none is defined). 1-D y or u are read as one channel.
    """

    y: np.ndarray
    u: np.ndarray | None = None
    sampling_time: float | None = None
    name: str = ""
    init_window: int = 0

    def __post_init__(self) -> None:
        where = f"record {self.name!r}" if self.name else "record"
        y = _as_2d("y", self.y, where)
        object.__setattr__(self, "y", y)
        if self.u is not None:
            u = _as_2d("u", self.u, where)
            if len(u) != len(y):
                raise MopError(f"{where}: u has {len(u)} steps and y {len(y)}; they must be sampled together")
            if not np.isfinite(u).all():
                raise MopError(f"{where}: u holds NaN or Inf; inputs must be complete, fill them")
            object.__setattr__(self, "u", u)
        if np.isinf(y).any():
            raise MopError(f"{where}: y holds Inf; leave a missing output as NaN")
        if self.sampling_time is not None and not (
            math.isfinite(self.sampling_time) and self.sampling_time > 0
        ):
            raise MopError(
                f"{where}: sampling_time {self.sampling_time} must be a positive number of seconds"
            )
        if not 0 <= self.init_window <= len(y):
            raise MopError(f"{where}: init_window {self.init_window} must be in [0, {len(y)}] (its length)")

    def __len__(self) -> int:
        return len(self.y)

    def __repr__(self) -> str:
        dt = "" if self.sampling_time is None else f", sampling_time={self.sampling_time}"
        return (
            f"Record({self.name!r}, T={len(self)}, m={self.num_outputs}, k={self.num_inputs}{dt}, "
            f"init_window={self.init_window})"
        )

    def __getitem__(self, steps: slice) -> Record:
        """The record of the time steps `steps` (a slice); its init_window is kept where it still fits."""
        if not isinstance(steps, slice):
            raise TypeError("a Record is sliced in time with a slice, e.g. record[100:2000]")
        y = self.y[steps]
        return dataclasses.replace(
            self,
            y=y,
            u=None if self.u is None else self.u[steps],
            init_window=min(self.init_window, len(y)),
        )

    @property
    def num_outputs(self) -> int:
        return self.y.shape[1]

    @property
    def num_inputs(self) -> int:
        return 0 if self.u is None else self.u.shape[1]

    @property
    def pair(self) -> Pair:
        """(y, u) as the functions of mop.records, mop.identify and mop.train take one record."""
        return self.y, self.u

    def split(self, fraction: float) -> tuple[Record, Record]:
        """(first part, last part) in time; the last part is ceil(fraction * T) steps (never rounded away)."""
        if not 0 < fraction < 1:
            raise MopError(f"split fraction {fraction} must be in (0, 1)")
        tail = math.ceil(fraction * len(self))
        if tail >= len(self):
            raise MopError(f"record {self.name!r}: {len(self)} steps are too few to hold out {fraction:.0%}")
        return self[: len(self) - tail], self[len(self) - tail :]


# what a function taking records accepts: one Record, a sequence of them, or (y, u) pairs (the older form)
RecordsLike = Record | Sequence[Record] | Sequence[Pair]


def to_records(data: RecordsLike) -> list[Record]:
    """The records of `data` (RecordsLike); pairs become records named by their position, as read_records
    names a .npz's. The one place pairs turn into records for the functions that take records."""
    if isinstance(data, Record):
        return [data]
    if all(isinstance(r, Record) for r in data):
        return list(data)
    return from_pairs(data)


def as_pairs(records: Sequence[Record]) -> list[Pair]:
    """The records as the list of (y, u) pairs the older functions take."""
    return [r.pair for r in records]


def from_pairs(pairs: Sequence[Pair], names: Sequence[str] | None = None, **fields) -> list[Record]:
    """Records from (y, u) pairs (and names); `fields` (sampling_time, init_window) apply to each."""
    names = list(names) if names is not None else [str(i) for i in range(len(pairs))]
    return [Record(y=y, u=u, name=n, **fields) for (y, u), n in zip(pairs, names, strict=True)]


def read_records(path: str | os.PathLike, sampling_time: float | None = None) -> list[Record]:
    """The records of a .csv or .npz file (mop.io's formats), read once; sampling_time: the given one, else
    the one a CSV's time column in seconds gives, else None."""
    names, pairs, dt = read_timed(path)
    return from_pairs(pairs, names, sampling_time=dt if sampling_time is None else sampling_time)


def fingerprint(pairs: Sequence[tuple[np.ndarray, np.ndarray | None]]) -> str:
    """A SHA-256 digest of records' values (y, u) as float64, shapes included: the same samples give the same
    digest whatever file they were read from, so a model can tell its own training record when it sees it."""
    digest = hashlib.sha256()
    for y, u in pairs:
        for a in (y, np.zeros((len(y), 0)) if u is None else u):
            a = np.ascontiguousarray(a, dtype=np.float64)
            digest.update(str(a.shape).encode())
            digest.update(a.tobytes())
    return digest.hexdigest()


def write_records(records: Sequence[Record], path: str | os.PathLike) -> Path:
    """Write records as mop.io's long CSV `trajectory,t,y0..,u0..` (values as repr: read back bit for bit;
    a missing output an empty cell), atomically; returns the path. Names default to r0, r1, ..."""
    path = Path(path)
    if not records:
        raise MopError(f"{path}: no records to write")
    m, k = records[0].num_outputs, records[0].num_inputs
    if any((r.num_outputs, r.num_inputs) != (m, k) for r in records):
        raise MopError(f"{path}: the records differ in their channels; write one kind per file")
    names = [r.name or f"r{i}" for i, r in enumerate(records)]
    if len(set(names)) != len(names):
        raise MopError(f"{path}: two records share a name; name them apart")
    header = ["trajectory", "t", *[f"y{i}" for i in range(m)], *[f"u{i}" for i in range(k)]]
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        for name, r in zip(names, records, strict=True):
            for t in range(len(r)):
                ys = ["" if np.isnan(v) else repr(float(v)) for v in r.y[t]]
                us = [] if r.u is None else [repr(float(v)) for v in r.u[t]]
                w.writerow([name, t, *ys, *us])
    return path
