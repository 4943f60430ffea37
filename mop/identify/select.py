"""Fit an identifier on an estimation record, its orders chosen on a held-out part of that record.

The last HOLDOUT (20%) of the steps of every trajectory is held out: each order of the grid is fitted on the
first 80% and scored on the held-out steps, by default in free-run simulation after the first 80% as the
context (simulate(traj, cut): the system-identification benchmarks' protocol), or one step ahead
(predict(traj)[cut:]); the score is the RMSE over every held-out output. The smallest model (fewest
coefficients, then grid order) whose score is within TOLERANCE (1%) of the lowest wins: orders above the
system's differ from it on held-out data by noise alone (on a known ARX(2, 2) record the lowest score fell
to (4, 4) by 0.01%). That order is refitted on the whole record. Deterministic.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mop.errors import MopError
from mop.identify.linear import IDENTIFIERS, Arrays, FittedPredictor
from mop.record import Record, RecordsLike, fingerprint, to_records
from mop.systems.base import Trajectories

HOLDOUT = 0.2
TOLERANCE = 0.01
SIMULATION, ONE_STEP = "simulation", "one-step"  # the --select criteria
CRITERIA = (SIMULATION, ONE_STEP)
SCORE = "rmse"  # the held-out score's key in fitted.json's grid
POLE_RADIUS = "pole_radius"  # fitted.json: the chosen model's largest pole modulus


def complete_record(records: list[Record], source: str) -> Arrays:
    """[(y, u)] with u (T, 0) where there are no inputs; MopError for missing outputs."""
    missing = sum(int(np.isnan(r.y).sum()) for r in records)
    if missing:
        raise MopError(
            f"{source}: {missing} output(s) missing (NaN / empty cells); fitted identifiers need every "
            "output of the estimation record: fill the gaps or cut the record at them"
        )
    return [(r.y, np.zeros((len(r), 0)) if r.u is None else r.u) for r in records]


def input_range(record: Arrays) -> list[list[float]]:
    """[means, stds] of the estimation record's inputs u0.. (per channel): a fitted model warns when it is
    driven far outside them (FittedPredictor.check_inputs)."""
    u = np.concatenate([u for _, u in record])
    return [u.mean(axis=0).tolist(), np.maximum(u.std(axis=0), 1e-12).tolist()]


def holdout_cut(length: int) -> int:
    """The first held-out index of a trajectory of `length` outputs: the last 20% (at least one) held out."""
    return length - max(1, math.ceil(HOLDOUT * length))


def score(predictor: FittedPredictor, data: Arrays, select: str) -> float:
    """RMSE over the held-out outputs y_cut..y_T of every trajectory (inf where a prediction is not
    finite)."""
    with np.errstate(over="ignore", invalid="ignore"):  # an unstable candidate overflows: it scores inf
        return _score(predictor, data, select)


def _score(predictor: FittedPredictor, data: Arrays, select: str) -> float:
    errors = []
    for y, u in data:
        cut = holdout_cut(len(y))
        traj = Trajectories(y=torch.from_numpy(y)[None], u=torch.from_numpy(u)[None] if u.shape[1] else None)
        if select == SIMULATION:
            pred = predictor.simulate(traj, cut)[0].numpy()
        else:
            pred = predictor.predict(traj)[0, cut:].numpy()
        errors.append(y[cut:] - pred)
    e = np.concatenate(errors)
    return float(np.sqrt((e**2).mean())) if np.isfinite(e).all() else math.inf


def choose(candidates: list[dict[str, int]], scores: list[float], size: Any, spread: float) -> dict[str, int]:
    """The candidate of smallest size(c) (then the first in grid order) scoring within TOLERANCE of the best
    (or within 1e-4 of the outputs' standard deviation: noise-free data, fit by several orders to
    round-off)."""
    good = [i for i, s in enumerate(scores) if s <= (1 + TOLERANCE) * min(scores) + 1e-4 * spread]
    return candidates[min(good, key=lambda i: (size(candidates[i]), i))]


def largest_feasible(identifier: Any, data: Arrays, max_order: int) -> int:
    """The largest P <= max_order whose whole grid the record can fit (0 if none)."""
    k = data[0][1].shape[1]
    for P in range(max_order, 0, -1):
        if all(identifier.feasible(data, c, P) for c in identifier.candidates(P, k)):
            return P
    return 0


def check_length(kind: str, identifier: Any, data: Arrays, est: Arrays, max_order: int, source: str) -> None:
    """MopError before any fit when the estimation part is too short for the grid up to max_order."""
    P = largest_feasible(identifier, est, max_order)
    if P == max_order:
        return
    steps = sum(len(y) for y, _ in data)
    hint = f"use --max-order {P} or a longer record" if P else "give a longer record"
    raise MopError(
        f"{source}: {steps} steps ({sum(len(y) for y, _ in est)} after holding out the last "
        f"{HOLDOUT:.0%} of each trajectory) are too few to fit {kind} orders up to {max_order}; {hint}"
    )


def feasible_order(kind: str, data: RecordsLike, max_order: int = 10, source: str = "record") -> int:
    """The largest P <= max_order for which `fit(kind, data, max_order=P)` has enough steps (0: none)."""
    return largest_order(kind, complete_record(to_records(data), source), max_order)


def largest_order(kind: str, record: Arrays, max_order: int = 10) -> int:
    """feasible_order on complete arrays [(y (T, m), u (T, k))]."""
    est = [(y[: holdout_cut(len(y))], u[: holdout_cut(len(y))]) for y, u in record]
    return largest_feasible(IDENTIFIERS.get(kind), est, max_order)


def fit(
    kind: str, data: RecordsLike, select: str = SIMULATION, max_order: int = 10, source: str = "record"
) -> FittedPredictor:
    """The fitted `kind` ("arx" or "n4sid") with the orders that scored best on the held-out steps, refitted
    on the whole record. data: a mop.Record or a sequence of them (or (y, u) pairs, mop.record.to_records).
    The predictor's info records the estimation source, the criterion and every order's held-out score."""
    identifier = IDENTIFIERS.get(kind)
    if select not in CRITERIA:
        raise MopError(f"--select must be one of {', '.join(CRITERIA)}, got {select!r}")
    if not isinstance(max_order, int) or max_order < 1:
        raise MopError(f"--max-order must be an integer >= 1, got {max_order!r}")
    record = complete_record(to_records(data), source)
    info = {"estimation": Path(source).name, "select": select, "max_order": max_order, "holdout": HOLDOUT}
    info["fingerprint"] = fingerprint(record)  # mop predict warns when it is asked to score this record
    info["input_range"] = input_range(record)
    best, candidates, scores = _grid_choice(kind, record, info, select, max_order, source)
    fitted = identifier.fit_grid(record, [best], info, max_order)[0]
    # a diverged order's score is written as null (JSON has no inf)
    rmse = [s if math.isfinite(s) else None for s in scores]
    fitted.info["grid"] = [{**c, SCORE: s} for c, s in zip(candidates, rmse, strict=True)]
    fitted.info[POLE_RADIUS] = pole_radius(fitted.model.A)
    return fitted


def chosen_orders(
    kind: str, record: Arrays, max_order: int = 10, source: str = "record", select: str = SIMULATION
) -> dict[str, int]:
    """The orders `fit` chooses on complete arrays [(y (T, m), u (T, k))], without its refit on the whole
    record or its provenance (a planner's question: which orders, not which model)."""
    return _grid_choice(kind, record, {}, select, max_order, source)[0]


def _grid_choice(
    kind: str, record: Arrays, info: dict[str, Any], select: str, max_order: int, source: str
) -> tuple[dict[str, int], list[dict[str, int]], list[float]]:
    """(the chosen orders, the candidates, their held-out scores): every candidate up to max_order fitted on
    the record's first 80% and scored on the rest (`select`), the smallest within TOLERANCE of the best."""
    identifier = IDENTIFIERS.get(kind)
    est = [(y[: holdout_cut(len(y))], u[: holdout_cut(len(y))]) for y, u in record]
    check_length(kind, identifier, record, est, max_order, source)
    candidates = identifier.candidates(max_order, record[0][1].shape[1])
    grid = identifier.fit_grid(est, candidates, info, max_order)
    scores = [score(p, record, select) for p in grid]
    if not np.isfinite(scores).any():
        raise MopError(
            f"{source}: every {kind} order of the grid diverged on the held-out steps; check the data"
        )
    m, k = record[0][0].shape[1], record[0][1].shape[1]
    spread = float(np.concatenate([y for y, _ in record]).std())
    best = choose(candidates, scores, lambda c: identifier.size(c, m, k), spread)
    return best, candidates, scores


def fit_orders(
    kind: str, data: RecordsLike, orders: dict[str, int], max_order: int = 10, source: str = "record"
) -> FittedPredictor:
    """The `kind` model of the given orders (e.g. {"p": 2, "q": 2}, {"n": 3}) fitted on the whole record, no
    order chosen; max_order sets what the grid would (N4SID's block rows, at least those of the order).
    MopError, before any fit, where the record is too short for those orders."""
    identifier = IDENTIFIERS.get(kind)
    record = complete_record(to_records(data), source)
    k = record[0][1].shape[1]
    ints = bool(orders) and all(isinstance(v, int) and v >= 0 for v in orders.values())
    largest = max(max_order, *orders.values()) if ints else max_order
    valid = identifier.candidates(largest, k)
    if orders not in valid:
        inputs = f"{k} input(s)" if k else "no inputs"
        raise MopError(
            f"{kind} orders {orders} do not fit a record with {inputs}; give orders like {valid[-1]}"
        )
    if not identifier.feasible(record, orders, largest):
        steps = sum(len(y) for y, _ in record)
        raise MopError(f"{source}: {steps} steps are too few to fit {kind} {orders}; lower the orders")
    info = {"estimation": Path(source).name, "select": "given", "max_order": largest}
    info["fingerprint"] = fingerprint(record)
    info["input_range"] = input_range(record)
    fitted = identifier.fit_grid(record, [orders], info, largest)[0]
    fitted.info[POLE_RADIUS] = pole_radius(fitted.model.A)
    return fitted


def pole_radius(A: np.ndarray) -> float:
    """The largest modulus of A's eigenvalues (the fitted model's poles); >= 1: its free run does not
    decay, and above 1 grows without bound (tank_records plant 4's N4SID: 1.034, a 1024-step record
    simulated to 3e13, although its held-out 20% scored 0.90)."""
    return float(np.abs(np.linalg.eigvals(A)).max()) if A.size else 0.0
