"""Reading users' measured trajectories (.csv long format or .npz as `mop simulate` writes).

CSV: a header, one row per (trajectory, time step): columns `trajectory, t, y0..y{m-1}[, u0..u{k-1}]`, the
value columns read by their names in any order (`t,u0,y0` is the output y0 and the input u0).
Trajectories may have different lengths; t runs 0..T_i within each trajectory (rows in any order), or is time
in seconds (`0.00, 0.01, ..`, as MATLAB's iddata or a logger writes it): uniform within a relative 1e-3,
the same step in every trajectory, any start; that step is the records' sampling time. One record, as
identification data comes, may leave out the trajectory column (`t, y0.., u0..`: one trajectory named after
the file) or both (`y0.., u0..`: one trajectory, its rows in time order); every column, t and trajectory
too, may stand anywhere in the header.
NPZ: arrays y (B, T+1, m) and optionally u (B, T+1, k).
Missing outputs: an empty CSV cell (or NaN) in a y column, NaN in the .npz y, marks an output channel not
measured at that step; it stays NaN in the arrays returned (Trajectories.observed is the mask). Inputs u must
be complete. Inf, non-numbers and missing inputs are refused naming the line and column.
Every problem raises MopError with a one-line message.
"""

from __future__ import annotations

import contextlib
import csv
import math
import os
import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from mop.errors import MopError

# larger magnitudes are refused as garbage (an overflowed logger, a wrong column); records in large units
# (pressures in Pa, encoder counts) load, since every predictor normalises each channel
MAX_ABS = 1e12


def _check_values(name: str, a: np.ndarray, where: str, gaps: bool = False) -> None:
    """MopError for Inf, for NaN unless `gaps` (outputs: NaN marks a missing value), or |values| > MAX_ABS."""
    if np.isinf(a).any():
        raise MopError(f"{where}: {name} holds Inf; remove it, or leave it empty / NaN to mark it missing")
    if not gaps and np.isnan(a).any():
        raise MopError(f"{where}: {name} has missing values (NaN); inputs u must be complete, fill them")
    if a.size and np.nan_to_num(np.abs(a)).max() > MAX_ABS:
        raise MopError(
            f"{where}: {name} holds values up to {np.nanmax(np.abs(a)):.3g} (limit {MAX_ABS:.0e}); "
            "check the file (a garbled value?) or rescale that channel"
        )


def read_npz(path: Path) -> list[tuple[np.ndarray, np.ndarray | None]]:
    try:
        with np.load(path, allow_pickle=False) as d:
            if "y" not in d:
                raise MopError(f"{path}: no array 'y' (expected y (B, T+1, m), optional u)")
            y = np.asarray(d["y"], dtype=np.float64)
            u = np.asarray(d["u"], dtype=np.float64) if "u" in d else None
    except MopError:
        raise
    except Exception as e:
        raise MopError(f"{path}: not a readable .npz file ({type(e).__name__})") from None
    if y.ndim != 3 or y.shape[1] < 2 or y.shape[0] < 1:
        raise MopError(f"{path}: y has shape {y.shape}; need (B, T+1, m) with at least 2 time steps")
    if u is not None and (u.ndim != 3 or u.shape[:2] != y.shape[:2]):
        raise MopError(f"{path}: u has shape {u.shape}; need (B, T+1, k) matching y {y.shape}")
    _check_values("y", y, str(path), gaps=True)
    empty = np.isnan(y).all(axis=(1, 2))
    if empty.any():
        raise MopError(
            f"{path}: trajectory {int(empty.argmax())} has no measured output (y all NaN); drop it or fill it"
        )
    if u is not None:
        _check_values("u", u, str(path))
    return [(y[b], None if u is None else u[b]) for b in range(y.shape[0])]


def read_csv(path: Path) -> tuple[list[str], list[tuple[np.ndarray, np.ndarray | None]]]:
    """(names, [(y, u)]) of a CSV (see the module docstring)."""
    names, data, _ = read_csv_timed(path)
    return names, data


TIME_TOLERANCE = 1e-3  # relative spread of the steps of a time column in seconds that still reads as uniform


def read_csv_timed(path: Path) -> tuple[list[str], Data, float | None]:
    """(names, [(y, u)], sampling time in seconds or None where t counts steps) of a CSV."""
    try:
        with open(path, newline="") as f:
            rows = list(csv.reader(f))
    except (OSError, UnicodeDecodeError) as e:
        raise MopError(f"{path}: cannot read ({type(e).__name__})") from None
    rows = [r for r in rows if any(c.strip() for c in r)]
    if not rows:
        raise MopError(f"{path}: file is empty; expected a header `trajectory,t,y0,...` and rows")
    written = ",".join(c.strip() for c in rows[0])  # the header as the user wrote it, for messages
    rows = _with_trajectory_column([c.strip() for c in rows[0]], rows, path)
    header = [c.strip() for c in rows[0]]
    if header[:2] != ["trajectory", "t"] or len(header) < 3:
        raise MopError(
            f"{path}: header {written!r} is not `trajectory,t,y0..y{{m-1}}[,u0..u{{k-1}}]` "
            "(or, for one record, `t,y0..` or `y0..`; columns in any order)"
        )
    ycols, ucols = _value_columns(header, written, path)
    times: dict[str, dict[float, list[float]]] = {}
    for n, r in enumerate(rows[1:], start=2):
        if len(r) != len(header):
            raise MopError(f"{path}: line {n} has {len(r)} columns, the header has {len(header)}")
        try:
            t = float(r[1])
            if not math.isfinite(t):
                raise ValueError
        except ValueError:
            raise MopError(
                f"{path}: line {n}, column t: {r[1]!r} is neither a time step 0, 1, .. nor a time in seconds"
            ) from None
        vals = [_cell(r[i], header[i], path, n) for i in (*ycols, *ucols)]  # y0.., u0.. by name
        steps = times.setdefault(r[0].strip(), {})
        if t in steps:
            raise MopError(f"{path}: line {n}: trajectory {r[0]!r} has time {r[1]!r} twice")
        steps[t] = vals
    if not times:
        raise MopError(f"{path}: no data rows below the header")
    trajs, sampling_time = _as_steps(times, path)
    out = []
    m = len(ycols)
    for name, steps in trajs.items():
        ts = sorted(steps)
        if ts != list(range(len(ts))):
            raise MopError(f"{path}: trajectory {name!r} time steps must be 0..T without gaps")
        if len(ts) < 2:
            raise MopError(f"{path}: trajectory {name!r} has one row; need at least 2 time steps")
        a = np.array([steps[t] for t in ts])  # (T+1, m+k)
        _check_values(f"trajectory {name!r}", a, str(path), gaps=True)
        if np.isnan(a[:, :m]).all():
            raise MopError(f"{path}: trajectory {name!r} has no measured output (every y cell empty)")
        out.append((a[:, :m], a[:, m:] if ucols else None))
    return list(trajs), out, sampling_time


def _as_steps(
    times: dict[str, dict[float, list[float]]], path: Path
) -> tuple[dict[str, dict[int, list[float]]], float | None]:
    """({trajectory: {step: values}}, sampling time): t as written where every trajectory counts its steps
    0, 1, .. (sampling time None); else t read as seconds, uniform within TIME_TOLERANCE, one step for all."""
    counted = all(
        all(float(t).is_integer() for t in steps) and sorted(steps) == list(range(len(steps)))
        for steps in times.values()
    )
    if counted:
        return {name: {int(t): v for t, v in steps.items()} for name, steps in times.items()}, None
    dts = {}
    for name, steps in times.items():
        ts = np.array(sorted(steps))
        if len(ts) < 2:
            raise MopError(f"{path}: trajectory {name!r} has one row; need at least 2 time steps")
        diffs = np.diff(ts)
        dt = float(np.median(diffs))
        if np.abs(diffs - dt).max() > TIME_TOLERANCE * dt:
            j = int(np.abs(diffs - dt).argmax())
            raise MopError(
                f"{path}: trajectory {name!r}: column t is neither the steps 0..T nor uniform time in "
                f"seconds (step {dt:.6g} s, but {diffs[j]:.6g} s after t = {ts[j]:.6g}); resample the "
                "record or number its rows 0..T"
            )
        dts[name] = dt
    dt = float(np.median(list(dts.values())))
    odd = next((n for n, d in dts.items() if abs(d - dt) > TIME_TOLERANCE * dt), None)
    if odd is not None:
        raise MopError(
            f"{path}: trajectory {odd!r} is sampled every {dts[odd]:.6g} s and others every {dt:.6g} s; "
            "give records of one sampling time per file"
        )
    steps = {
        name: {int(round((t - min(values)) / dt)): v for t, v in values.items()}
        for name, values in times.items()
    }
    return steps, dt


def _value_columns(header: list[str], written: str, path: Path) -> tuple[list[int], list[int]]:
    """(positions of y0..y{m-1}, positions of u0..u{k-1}) in `header`, found by name in any order; a
    duplicate, a gap in the numbering or an unknown name is refused naming the column."""
    found: dict[str, dict[int, int]] = {"y": {}, "u": {}}
    for i, name in enumerate(header[2:], start=2):
        match = re.fullmatch(r"([yu])(\d+)", name)
        if match is None:
            raise MopError(
                f"{path}: column {name!r} of header {written!r} is neither an output y<i> nor an input u<j> "
                "(nor t or trajectory): name the outputs y0, y1, .. and the inputs u0, u1, .. (or, for one "
                "record, `t,y0..` or `y0..`; columns in any order, t in steps or seconds)"
            )
        kind, number = match.group(1), int(match.group(2))
        if number in found[kind]:
            raise MopError(f"{path}: column {name!r} appears twice in header {written!r}; name each once")
        found[kind][number] = i
    if not found["y"]:
        raise MopError(f"{path}: header {written!r} has no output column; name the outputs y0, y1, ..")
    for kind, columns in found.items():
        gap = next((j for j in range(len(columns)) if j not in columns), None)
        if gap is not None:
            raise MopError(
                f"{path}: header {written!r} has {', '.join(f'{kind}{j}' for j in sorted(columns))} but no "
                f"{kind}{gap}; number the {'outputs' if kind == 'y' else 'inputs'} from {kind}0 without gaps"
            )
    return [found["y"][j] for j in sorted(found["y"])], [found["u"][j] for j in sorted(found["u"])]


def _with_trajectory_column(header: list[str], rows: list[list[str]], path: Path) -> list[list[str]]:
    """rows in the long format `trajectory, t, values..`: the columns trajectory and t moved first wherever
    they stand; without trajectory, one record named after the file; without t, the steps 0..T in row order
    (within each trajectory)."""
    where = {c: header.index(c) for c in ("trajectory", "t") if c in header}
    values = [i for i, c in enumerate(header) if c not in where]
    counts: dict[str, int] = {}
    out = [["trajectory", "t", *[header[i] for i in values]]]
    for n, r in enumerate(rows[1:], start=2):
        if len(r) != len(header):
            raise MopError(f"{path}: line {n} has {len(r)} columns, the header has {len(header)}")
        name = r[where["trajectory"]] if "trajectory" in where else path.stem
        if "t" in where:
            t = r[where["t"]]
        else:
            t = str(counts.get(name, 0))
            counts[name] = int(t) + 1
        out.append([name, t, *[r[i] for i in values]])
    return out


def _cell(text: str, column: str, path: Path, line: int) -> float:
    """One CSV value: a number; empty or NaN is a missing output (NaN); Inf, garbage or a missing input is
    refused naming the line and column."""
    text = text.strip()
    try:
        value = float(text) if text else float("nan")
    except ValueError:
        raise MopError(f"{path}: line {line}, column {column}: {text!r} is not a number") from None
    if math.isinf(value) and column.startswith("u"):
        raise MopError(
            f"{path}: line {line}, column {column}: the input {text!r} is infinite; inputs must be finite"
        )
    if math.isinf(value):
        raise MopError(
            f"{path}: line {line}, column {column}: {text!r} is infinite; leave the cell empty to mark a "
            "missing output"
        )
    if math.isnan(value) and column.startswith("u"):
        raise MopError(
            f"{path}: line {line}, column {column}: the input is missing; inputs u must be complete, fill it"
        )
    return value


Data = list[tuple[np.ndarray, np.ndarray | None]]


# file version (path, mtime, size) -> what read_trajectories returned, while a reading_once() block runs
_read_once: dict[tuple, tuple[list[str], Data, float | None]] | None = None


@contextlib.contextmanager
def reading_once() -> Iterator[None]:
    """Within the block, read_trajectories parses each version of a file (its path, mtime and size) once and
    hands every caller its own copy of the arrays: `mop train --data FILE` reads FILE once, however many
    steps of its recipe look at the record. Nested blocks share the outer one's memory."""
    global _read_once
    outer = _read_once
    _read_once = {} if outer is None else outer
    try:
        yield
    finally:
        _read_once = outer


def read_trajectories(path: str | os.PathLike) -> tuple[list[str], Data]:
    """(names, [(y (T_i+1, m), u (T_i+1, k) | None)]) from a .csv or .npz file (read once per version of the
    file inside a reading_once() block)."""
    names, data, _ = read_timed(path)
    return names, data


def read_timed(path: str | os.PathLike) -> tuple[list[str], Data, float | None]:
    """(names, data, sampling time in seconds or None): read_trajectories with the sampling time that a CSV's
    time column in seconds gives (None for step counts and .npz files)."""
    path = Path(path)
    if not path.is_file():
        raise MopError(f"data file {path} does not exist")
    if _read_once is None:
        return _read_file(path)
    stat = path.stat()
    key = (os.path.abspath(path), stat.st_mtime_ns, stat.st_size)
    if key not in _read_once:
        _read_once[key] = _read_file(path)
    names, data, dt = _read_once[key]
    return list(names), [(y.copy(), None if u is None else u.copy()) for y, u in data], dt


def _read_file(path: Path) -> tuple[list[str], Data, float | None]:
    if path.suffix == ".npz":
        data = read_npz(path)
        return [str(i) for i in range(len(data))], data, None
    if path.suffix == ".csv":
        return read_csv_timed(path)
    raise MopError(f"{path}: unknown data format {path.suffix!r}; use .csv or .npz")


def read_system(path: str | os.PathLike, num_trajectories: int) -> tuple[str, dict[str, np.ndarray]]:
    """(family, {name: array}) from the `family` string array and the `param_<name>` arrays (each with leading
    dim B = num_trajectories) that `mop simulate` writes next to y and u; ("", {}) where the file has none."""
    path = Path(path)
    if path.suffix != ".npz":
        return "", {}
    try:
        with np.load(path, allow_pickle=False) as d:
            family = str(d["family"]) if "family" in d else ""
            params = {k[len("param_") :]: np.asarray(d[k]) for k in d.files if k.startswith("param_")}
    except Exception as e:
        raise MopError(f"{path}: not a readable .npz file ({type(e).__name__})") from None
    for name, a in params.items():
        if a.ndim == 0 or a.shape[0] != num_trajectories:
            raise MopError(
                f"{path}: param_{name} has shape {a.shape}; need leading dim {num_trajectories} (one per y)"
            )
    return family, params
