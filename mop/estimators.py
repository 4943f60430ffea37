"""Estimators with one face: ARX, N4SID and the learned model, each built with its options, fitted on records,
then asked for one-step predictions, k-step forecasts and free-run simulations in the records' units.

    from mop.estimators import ARX, N4SID, Learned
    est, val = mop.read_records("est.csv")[0], mop.read_records("val.csv")[0]
    for model in (ARX(), N4SID(), Learned(budget_minutes=2)):
        ysim = model.fit(est).simulate(val, init=50)         # (T, m), NaN for t < 50

The data an estimator takes: a mop.record.Record, a list of Records, a path to a .csv / .npz (mop.io's
formats), or arrays (y, u) with y (T, m) or (T,) and u (T, k), (T,) or None, or y alone (one record; y
(B, T, m) with u (B, T, k) is B records). What it returns follows what it was given: one array for one
record, a list for a list (or a file, or a batch).
Time convention (mop.predictors): predict(r)[t] predicts y_t from y_<t, u_<t; forecast(r, K)[t, j] predicts
y_{t+j} from y_<t and u_<t+j (NaN where t + j >= T); simulate(r, init=c)[t] predicts y_t for t >= c from
y_<c and the inputs alone (NaN for t < c), exactly the numbers `mop predict MODEL DATA --simulate c` writes
(init=0: from the record's start, y_0 its initial condition, t >= 1).

ARX and N4SID are mop.identify's fits (`mop fit arx|n4sid`); Learned trains through the path `mop train --data
FILE [--init RUN]` takes (mop.recipe.fit.fit_record, or fine_tune_record with init: the config, the
training, the held-out choice), on the records in memory: no file is written but the run (in out_dir, or in
a temporary directory removed with the estimator); the run's config names where the records came from (the
file, or the first record's name).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import shutil
import sys
import tempfile
import weakref
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mop.config import parse_overrides
from mop.errors import MopError
from mop.identify import is_fitted
from mop.identify.arx import ARX as ArxIdentifier
from mop.identify.linear import FittedPredictor
from mop.identify.n4sid import N4SID as N4sidIdentifier
from mop.identify.narx_model import FittedNARX, fit_cubic_narx
from mop.identify.select import SIMULATION, fit, fit_orders
from mop.identify.store import FILE as FITTED_FILE
from mop.identify.store import load as load_fitted
from mop.incontext import simulate_with_context
from mop.predictors import Predictor
from mop.pretrained import dimensions
from mop.recipe.fit import fine_tune_record, fit_record
from mop.recipe.selection import selection_line
from mop.record import Record, as_pairs, read_records
from mop.records import predict_all, simulate_all
from mop.runs import load_predictor
from mop.simulators import SimulatorConfig, fit_simulator
from mop.systems.base import Trajectories
from mop.train.records import TrainingRecords

Records = Record | Sequence[Record] | str | os.PathLike | tuple[Any, Any]


def as_records(data: Records, where: str = "data") -> tuple[list[Record], bool]:
    """(records, one): the records of `data` (see the module docstring) and whether it was a single record.
    MopError naming the shape for anything else, before any work."""
    if isinstance(data, Record):
        return [data], True
    if isinstance(data, (str, os.PathLike)):
        return read_records(data), False
    if isinstance(data, (list, tuple)) and data and all(isinstance(r, Record) for r in data):
        return list(data), False
    if isinstance(data, np.ndarray):  # outputs alone
        data = (data, None)
    if isinstance(data, tuple) and len(data) == 2:
        y = np.asarray(data[0], dtype=np.float64)
        u = None if data[1] is None else np.asarray(data[1], dtype=np.float64)
        if y.ndim == 3:
            if u is not None and (u.ndim != 3 or u.shape[:2] != y.shape[:2]):
                shape = u.shape
                raise MopError(f"{where}: y is {y.shape} (B, T, m), so u must be (B, T, k); got u {shape}")
            return [Record(y=y[b], u=None if u is None else u[b]) for b in range(len(y))], False
        if y.ndim in (1, 2):
            return [Record(y=y, u=u)], True
        raise MopError(f"{where}: y has shape {y.shape}; give y (T, m), (T,) or a batch (B, T, m)")
    raise MopError(
        f"{where}: got {type(data).__name__}; give a mop.record.Record, a list of them, a .csv / .npz path, "
        "or arrays (y, u) with y (T, m) and u (T, k) or None"
    )


class Estimator:
    """The face every estimator shares; a subclass sets `predictor_` (a mop Predictor) in `fit`."""

    name = "estimator"

    def __init__(self) -> None:
        self.predictor_: Predictor | None = None
        self.shape_: tuple[int, int] | None = None  # (m, k) of the records fitted on

    def fit(self, data: Records) -> Estimator:
        raise NotImplementedError

    def _records(self, data: Records) -> tuple[list[Record], bool]:
        if self.predictor_ is None:
            raise MopError(f"{self.name} is not fitted yet; call .fit(record) first")
        records, one = as_records(data)
        m, k = self.shape_
        for r in records:
            if (r.num_outputs, r.num_inputs) != (m, k):
                raise MopError(
                    f"{self.name} was fitted on {m} output(s) and {k} input(s); record {r.name!r} has "
                    f"{r.num_outputs} and {r.num_inputs}: give records with the estimation record's columns"
                )
        return records, one

    def _fitted_on(self, records: list[Record]) -> None:
        shapes = {(r.num_outputs, r.num_inputs) for r in records}
        if len(shapes) != 1:
            raise MopError(
                f"{self.name}: the records differ in their channels {sorted(shapes)}; fit on one kind"
            )
        self.shape_ = shapes.pop()

    def predict(self, data: Records) -> np.ndarray | list[np.ndarray]:
        """One-step predictions (T, m) per record: [t] predicts y_t from y_<t and u_<t."""
        records, one = self._records(data)
        out = predict_all(self.predictor_, as_pairs(records))
        return out[0] if one else out

    def forecast(self, data: Records, horizon: int) -> np.ndarray | list[np.ndarray]:
        """k-step forecasts (T, horizon, m) per record: [t, j] predicts y_{t+j} from y_<t (NaN past T)."""
        records, one = self._records(data)
        longest = max(len(r) for r in records)
        if not isinstance(horizon, int) or not 1 <= horizon <= longest:
            raise MopError(f"forecast horizon must be an integer in [1, {longest}] (the longest record)")
        out = predict_all(self.predictor_, as_pairs(records), steps=horizon)
        return out[0] if one else out

    def simulate(self, data: Records, init: int | None = None) -> np.ndarray | list[np.ndarray]:
        """Free-run simulations (T, m) per record: [t] for t >= c from y_<c and the inputs alone, NaN before.
        c = init, or each record's init_window where init is None; 0 simulates from the record's start with
        y_0 its initial condition, as `mop predict --simulate 0` (so [0] is NaN too)."""
        records, one = self._records(data)
        starts = [r.init_window if init is None else init for r in records]
        for r, c in zip(records, starts, strict=True):
            if not isinstance(c, (int, np.integer)) or not 0 <= c <= len(r) - 1:
                raise MopError(f"simulate init must be an integer in [0, {len(r) - 1}] for record {r.name!r}")
        out: list[np.ndarray] = [np.empty(0)] * len(records)
        for context in sorted({max(int(c), 1) for c in starts}):
            idx = [i for i, c in enumerate(starts) if max(int(c), 1) == context]
            sims = simulate_all(self.predictor_, as_pairs([records[i] for i in idx]), context)
            for i, sim in zip(idx, sims, strict=True):
                full = np.full_like(records[i].y, np.nan)
                full[context:] = sim
                out[i] = full
        return out[0] if one else out


class _Identified(Estimator):
    """An identifier of mop.identify: its orders given, or chosen on the held-out 20% (`mop fit`)."""

    kind = ""

    def __init__(self, orders: dict[str, int] | None, select: str, max_order: int) -> None:
        super().__init__()
        self.orders, self.select, self.max_order = orders, select, max_order
        self.name = self.kind.upper()

    def fit(self, data: Records) -> Estimator:
        """Fit on `data`; the fit's info names its estimation record (fitted.json's "estimation"): the file
        for a path, else the first record's name."""
        records, _ = as_records(data)
        self._fitted_on(records)
        source = _source(data, records)
        if self.orders is None:
            self.predictor_ = fit(self.kind, records, self.select, self.max_order, source=source)
        else:
            self.predictor_ = fit_orders(self.kind, records, self.orders, self.max_order, source=source)
        return self

    @property
    def chosen_orders(self) -> dict[str, int]:
        """The orders fitted (given, or chosen by the held-out score)."""
        if self.predictor_ is None:
            raise MopError(f"{self.name} is not fitted yet; call .fit(record) first")
        return dict(self.predictor_.orders)


class ARX(_Identified):
    """ARX(na, nb) by least squares with an intercept (mop.identify.arx): na output lags, nb input lags (0
    without inputs). Orders left None are chosen as `mop fit arx` does: the grid up to max_order scored by
    `select` ("simulation" or "one-step") on the last 20% of each record, then refitted on all of it."""

    kind = ArxIdentifier.kind

    def __init__(
        self, na: int | None = None, nb: int | None = None, select: str = SIMULATION, max_order: int = 10
    ) -> None:
        if (na is None) != (nb is None):
            raise MopError("ARX: give both orders na and nb, or neither (chosen on held-out data)")
        super().__init__(None if na is None else {"p": na, "q": nb}, select, max_order)


class N4SID(_Identified):
    """N4SID subspace identification (mop.identify.n4sid) of state order `order`; None: chosen as `mop fit
    n4sid` does (see ARX)."""

    kind = N4sidIdentifier.kind

    def __init__(self, order: int | None = None, select: str = SIMULATION, max_order: int = 10) -> None:
        super().__init__(None if order is None else {"n": order}, select, max_order)


class LRU(Estimator):
    """A deep-LRU simulator fitted on its simulation error (mop.simulators): the plant's outputs from its
    inputs, started from the `init_window` measured steps before a simulation. options: the other fields of
    mop.simulators.SimulatorConfig (steps, subsection, width, state, layers, batch, lr, seed, ...)."""

    name = "LRU"

    def __init__(self, init_window: int = 50, **options: Any) -> None:
        super().__init__()
        fields = {f.name for f in dataclasses.fields(SimulatorConfig)}
        unknown = sorted(set(options) - fields)
        if unknown:
            raise MopError(
                f"LRU: unknown option(s) {', '.join(unknown)}; choose from {', '.join(sorted(fields))}"
            )
        self.config = SimulatorConfig(init_window=init_window, **options)

    def fit(self, data: Records) -> Estimator:
        """Fit on `data` (its last holdout share chooses the weights, mop.simulators.fit)."""
        records, _ = as_records(data)
        self._fitted_on(records)
        self.predictor_ = fit_simulator(records, self.config)
        return self


# the identifiers' estimators by mop.identify's kind (`mop fit KIND`)
IDENTIFIED: dict[str, type[_Identified]] = {ARX.kind: ARX, N4SID.kind: N4SID}


class Learned(Estimator):
    """The learned model trained on the records as `mop train --data FILE [--init RUN] key=value ...` trains.

    budget_minutes: the records recipe's budget (`mop train --budget`: steps planned from the minutes and the
    record's length, the same on every machine, mop.recipe.budget); for a fine-tune (init), train.steps is
    cut to the minutes over a measured step time (mop.train.estimate.step_seconds; machine-dependent).
    After a records-recipe fit, selection_ holds the held-out comparison with the fitted ARX and N4SID
    (mop.recipe.selection): where a linear model wins, predictor_ is that model, as mop.load(run_dir_) gives.
    init: fine-tune a run directory or pretrained:NAME (--init).
    overrides: dotted config keys, as keyword arguments with "__" for "." (train__steps=200) or as a dict
    (**{"train.steps": 200}). progress: the training's progress bar and the held-out check's verdict on
    standard error (default: where a terminal is attached). out_dir: where the run directory (out_dir/run)
    goes; without it, a temporary directory removed when the estimator is garbage-collected or the process
    ends (the predictor is held in memory). No file of the records is written. The seed is train.seed (0)."""

    name = "Learned"

    def __init__(
        self,
        budget_minutes: float | None = None,
        init: str | None = None,
        *,
        out_dir: str | os.PathLike | None = None,
        progress: bool | None = None,
        **overrides: Any,
    ) -> None:
        super().__init__()
        if budget_minutes is not None and not (
            isinstance(budget_minutes, (int, float)) and math.isfinite(budget_minutes) and budget_minutes > 0
        ):
            raise MopError(f"Learned: budget_minutes must be a positive number, got {budget_minutes!r}")
        self.budget_minutes, self.init = budget_minutes, init
        self.progress = sys.stderr.isatty() if progress is None else progress
        self.out_dir = None if out_dir is None else Path(out_dir)
        self.overrides = [f"{k.replace('__', '.')}={json.dumps(v)}" for k, v in overrides.items()]
        parse_overrides(self.overrides)
        self.run_dir_: Path | None = None

    def fit(self, data: Records, val: Records | None = None) -> Estimator:
        """Train on `data` (its last 10% validates, as `mop train --data`), or on all of it with `val` the
        validation records (--val). The run directory is run_dir_."""
        # where the records came from, for the run's config (data.path: provenance only): the file given,
        # else the first record's name ("record" without one); named before the one read of the file
        source, val_source = _path_of(data), _path_of(val)
        records, _ = as_records(data)
        self._fitted_on(records)
        val_records = None if val is None else tuple(as_records(val, "validation data")[0])
        given = TrainingRecords(
            tuple(records),
            val_records,
            source or records[0].name or "record",
            "" if val is None else val_source or val_records[0].name or "record",
        )
        base = self.out_dir or self._temporary_dir()
        base.mkdir(parents=True, exist_ok=True)
        if self.init is None:
            run = fit_record(
                base / "run",
                given,
                overrides=self.overrides,
                budget=self.budget_minutes,
                progress=self.progress,
            )
        else:
            run = fine_tune_record(
                base / "run",
                given,
                self.init,
                overrides=self.overrides,
                fine_tune_minutes=self.budget_minutes,
                progress=self.progress,
            )
        self.run_dir_ = run.run_dir
        if run.selection is not None:
            self.selection_ = run.selection
            if self.progress:
                print(f"Learned: {selection_line(run.selection)}", file=sys.stderr)
        fitted = self.run_dir_ / FITTED_FILE
        self.predictor_ = load_fitted(fitted.parent) if fitted.is_file() else load_predictor(self.run_dir_)
        return self

    def _temporary_dir(self) -> Path:
        """A new temporary directory for the run, removed when this estimator is garbage-collected or the
        process ends (its predictor_ is loaded in memory before)."""
        path = Path(tempfile.mkdtemp(prefix="mop-learned-"))
        weakref.finalize(self, shutil.rmtree, path, ignore_errors=True)
        return path


def _path_of(data: Records | None) -> str | None:
    """The path `data` names where it is a file, else None (records in memory)."""
    return str(data) if isinstance(data, (str, os.PathLike)) else None


def _source(data: Records, records: Sequence[Record]) -> str:
    """Where fitted records came from, for a fit's info: the file given, else the first record's name."""
    return _path_of(data) or records[0].name or "record"


class Loaded(Estimator):
    """A saved model as an estimator (`mop.load`): a trained run, `pretrained:NAME` or a `mop fit` folder,
    with the face of ARX() / Learned(): predict, forecast and simulate on a Record (or a list, a file,
    arrays), numpy out in the record's units; fit(record) trains it further on a record (a run or shipped
    model: the fine-tune of `mop train --data FILE --init RUN`; a fitted folder: the same kind and orders
    fitted anew).

    context: records a shipped class model reads before each simulation (`mop predict --context`,
    mop.incontext), in-context identification with no training.
    The predictor's own face stays: given mop.systems.base.Trajectories, predict / forecast / simulate return
    its tensors, and its attributes (model, cfg, info, ...) read through."""

    def __init__(self, spec: str | os.PathLike, predictor: Predictor, context: Records | None = None) -> None:
        super().__init__()
        self.spec, self.predictor_ = str(spec), predictor
        self.name = getattr(predictor, "name", self.spec)
        cfg = getattr(predictor, "cfg", None)
        if hasattr(predictor, "record_dims"):  # a network reading its feature's run (more inputs than k)
            self.shape_ = predictor.record_dims
        elif cfg is not None:
            self.shape_ = dimensions(dataclasses.asdict(cfg))
        else:
            self.shape_ = (predictor.output_dim, predictor.input_dim)
        self.context_ = None if context is None else as_records(context, "context")[0]
        self.run_dir_: Path | None = None

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__") or "predictor_" not in self.__dict__:
            raise AttributeError(name)
        return getattr(self.__dict__["predictor_"], name)

    def _records(self, data: Records) -> tuple[list[Record], bool]:
        if self.context_ is not None or getattr(self.predictor_, "cfg", None) is None:
            return super()._records(data)
        records, one = as_records(data)  # a class model reads one output at a time (mop.incontext)
        return records, one

    def predict(self, data: Records) -> Any:
        if isinstance(data, Trajectories):
            return self.predictor_.predict(data)
        return super().predict(data)

    def forecast(self, data: Records, horizon: int) -> Any:
        if isinstance(data, Trajectories):
            return self.predictor_.forecast(data, horizon)
        return super().forecast(data, horizon)

    def simulate(self, data: Records, init: int | None = None) -> Any:
        """As Estimator.simulate; with a context, each record is simulated after reading it (mop.incontext:
        the reading that simulates the context's own held-out end best). Trajectories: the predictor's
        simulate(traj, init) tensor."""
        if isinstance(data, Trajectories):
            return self.predictor_.simulate(data, init)
        if self.context_ is None:
            return super().simulate(data, init)
        records, one = as_records(data)
        out = []
        for r in records:
            c = r.init_window if init is None else init
            done = simulate_with_context(self.predictor_, r, max(int(c), 1), self.context_)
            full = np.full_like(r.y, np.nan)
            full[max(int(c), 1) :] = done.simulation
            out.append(full)
        return out[0] if one else out

    def fit(self, data: Records, **options: Any) -> Loaded:
        """Train further on `data`: a fitted folder (or a run that kept a least-squares model) is fitted anew
        with its kind and orders; a run or shipped model is fine-tuned (Learned(init=spec, **options), `mop
        train --data --init`)."""
        if isinstance(self.predictor_, FittedPredictor):
            records, _ = as_records(data)
            fitted = self.predictor_
            max_order = int(fitted.info.get("max_order", 10))
            self.predictor_ = fit_orders(
                fitted.kind, records, dict(fitted.orders), max_order, source=_source(data, records)
            )
            return self
        if isinstance(self.predictor_, FittedNARX):  # a records run that kept its least-squares feature
            records, _ = as_records(data)
            self.predictor_ = fit_cubic_narx(records, **self.predictor_.orders, source=_source(data, records))
            return self
        learned = Learned(init=self.spec, **options).fit(data)
        self.predictor_, self.run_dir_ = learned.predictor_, learned.run_dir_
        self.spec = str(learned.run_dir_)
        return self


def load(spec: str | os.PathLike, device: str = "cpu", context: Records | None = None) -> Loaded:
    """The model at `spec` as an estimator (see Loaded): a run directory (mop train), pretrained:NAME, or a
    `mop fit` folder; context: records a class model reads before each simulation (`--context`)."""
    predictor = load_fitted(spec) if is_fitted(spec) else load_predictor(spec, device=device)
    return Loaded(spec, predictor, context)
