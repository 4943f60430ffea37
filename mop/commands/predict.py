"""`mop predict PREDICTOR DATA`: predictions yhat_t (of y_t from y_<t, u_<t) for measured or simulated
trajectories, by a trained run (PREDICTOR a run directory of `mop train`) or a registered predictor (a name).

Predictors that need only y (and u) run on any .csv or .npz (those registered with needs_system=False, e.g.
rls, last). Predictors that know the system (needs_system=True, e.g. kalman, ekf) read it from the `family`
string array and the `param_<name>` arrays of an .npz written by `mop simulate`.

Output: CSV long format `trajectory,t,yhat0..` or NPZ yhat (B, T+1, m) (all trajectories of one length).
Trajectories of unequal lengths run in padded batches (see batches), equal to one at a time. A learned model
reads trajectories longer than its context C in windows of C steps starting every C/2 (mode "window" of
mop.models.predict), or with --stream through its KV cache.
With --steps K: k-step forecasts, forecast[t, j] predicting y_{t+j} from y_<t (j = 0..K-1, j = 0 the one-step
prediction; see mop.predictors.forecast): NPZ yhat (B, T+1, K, m) with NaN where t + j > T; CSV
`trajectory,t,j,yhat0..` with one row per (t, j), t + j <= T. Prints per-trajectory RMSE and mean ||e|| over
t >= 1 (one-step), or with --steps the mean ||y_{t+j} - forecast[t, j]|| per horizon k = j + 1 over t >= 1.
With --simulate C: free-run simulation (mop.predictors.simulate), y_C..y_T predicted from y_0..y_{C-1} and the
inputs alone: NPZ ysim (B, T+1-C, m), CSV `trajectory,t,y0..,ysim0..` for t >= C (the layout `mop benchmark`
writes too) and a figure beside it (OUT.png: simulated against measured, the RMSE in the legend); prints
the simulation RMSE beside the one-step RMSE over the same steps t >= C.
"""

from __future__ import annotations

import argparse
import csv
import math
import re
from pathlib import Path

import numpy as np
import torch

from mop.atomic import atomic_path
from mop.benchmarks.protocol import test_figure
from mop.errors import MopError
from mop.identify import is_fitted
from mop.identify import load as load_fitted
from mop.incontext import check_context, reading_line, simulate_with_context
from mop.io import read_system, read_timed
from mop.memory import check_allocation
from mop.predictors import (
    PREDICTORS,
    is_learned,
    make_predictor,
    needs_system,
)
from mop.pretrained import is_pretrained
from mop.record import Record, fingerprint, read_records
from mop.records import DIVERGENCE_FACTOR, divergence_step, observed_norms, predict_all, scores, simulate_all
from mop.runs import load_config, load_predictor
from mop.systems import FAMILIES
from mop.systems.base import (
    LINEAR_MODEL_ARRAYS,
    LinearModelParams,
    SystemParams,
    linear_model_from_params,
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "predictor",
        help="run directory of `mop train`, model directory of `mop fit`, pretrained:NAME (shipped: mop "
        "pretrained), or a registered predictor name; these need only the data: " + ", ".join(model_free()),
    )
    parser.add_argument("data", help="trajectories: .csv (trajectory,t,y0..,u0..) or .npz (y, u[, param_*])")
    parser.add_argument("--out", help="output .csv or .npz (default DATA_<predictor>_pred beside DATA)")
    parser.add_argument(
        "--stream",
        action="store_true",
        help="KV-cache streaming (constant cost per step; beyond a learned model's context an approximation, "
        "less accurate than the default windows)",
    )
    parser.add_argument("--steps", type=int, help="k-step forecasts for k = 1..STEPS (see above)")
    parser.add_argument(
        "--simulate",
        type=int,
        metavar="C",
        help="free-run simulation of y_C..y_T after a context of C outputs (0: from the start, y_0 its "
        "initial condition)",
    )
    parser.add_argument(
        "--context",
        metavar="FILE",
        help="with --simulate: an estimation record the model reads before each test record, as its "
        "in-context data: the last part its window holds, or (a class model) all of it as its feature's "
        "least-squares fit; the reading that simulates the record's own held-out end best is used, none "
        "where none beats the test alone (mop.incontext)",
    )


def model_free() -> list[str]:
    """The registered predictors that need neither the system nor a run directory (from their metadata)."""
    return [
        n
        for n in PREDICTORS.names()
        if not needs_system(n) and not is_learned(n) and not PREDICTORS.meta(n).get("needs_family")
    ]


BASELINE = "baseline:"  # baseline:NAME names a registered predictor even where a folder NAME exists


def resolve_predictor(spec: str, stream: bool = False):
    """(predictor, needs_system, what) for a fitted model (mop fit), a run directory, pretrained:NAME or a
    registered (non-learned) name, with `what` one line saying which of these ran.

    A bare name that is both a folder here and a registered predictor (`arx` after `mop fit arx --out arx`)
    is refused in one line, never resolved silently: `./arx` names the folder, `baseline:arx` the registered
    predictor."""
    registered = spec.removeprefix(BASELINE)
    if spec.startswith(BASELINE) or (not Path(spec).exists() and not is_pretrained(spec)):
        return _registered(registered)
    if spec in PREDICTORS.names() and Path(spec).is_dir() and "/" not in spec and "\\" not in spec:
        raise MopError(
            f"{spec!r} is both the folder ./{spec} and the registered predictor {spec}; give ./{spec} for "
            f"the folder or {BASELINE}{spec} for the registered one"
        )
    if is_fitted(spec):
        fitted = load_fitted(spec)
        return fitted, False, f"predictor: the model fitted by `mop fit` in {spec} ({fitted.name})"
    if is_pretrained(spec) or Path(spec).is_dir():
        loaded = load_predictor(spec, mode="stream" if stream else "window")
        kind = "the shipped model" if is_pretrained(spec) else "the trained run"
        return loaded, False, f"predictor: {kind} {spec}"
    return _registered(registered)


def _registered(name: str):
    names = PREDICTORS.names()
    if name not in names:
        raise MopError(
            f"{name!r}: run directory {name} does not exist and no predictor is registered under that name; "
            f"give a run directory, pretrained:NAME (mop pretrained lists them) or one of: "
            f"{', '.join(sorted(names))}"
        )
    if is_learned(name):
        raise MopError(f"{name} is a learned predictor: give its run directory (mop train --out DIR)")
    return (
        make_predictor(name),
        needs_system(name),
        f"predictor: the registered online predictor {name}, not a model fitted with `mop fit`",
    )


def system_of(name: str, data_path: Path, num: int, has_inputs: bool = False) -> tuple[str, SystemParams]:
    """The family and params a system-aware predictor needs from DATA, or a one-line MopError.

    A predictor registered with linear_model=True (kalman) also takes any linear-Gaussian model: where DATA
    has no family, or lacks that family's generator arrays, it needs param_A, param_C, param_Q, param_R
    (optional param_B, param_P0, param_x0_mean) and runs with family "" (linear_model_from_params)."""
    if data_path.suffix == ".csv":
        raise MopError(
            f"{name} needs the system's parameters, and a CSV has no system parameters; "
            f"give an .npz written by mop simulate, or use {', '.join(model_free())}"
        )
    family, params = read_system(data_path, num)
    linear_ok = bool(PREDICTORS.meta(name).get("linear_model"))
    missing = ["family"]
    if family:
        if family not in FAMILIES.names():
            raise MopError(f"{data_path}: family {family!r} is not one of {', '.join(FAMILIES.names())}")
        Params = FAMILIES.get(family).Params  # the fields the family's trajectories carry, from its type
        missing = [f"param_{k}" for k in Params.required() if k not in params]
        if not missing:
            return family, Params.from_arrays(params, by=name, where=str(data_path))
    if not linear_ok:
        raise MopError(f"{name} needs {', '.join(missing)} in {data_path}; write the file with mop simulate")
    lacking = [f"param_{k}" for k in LINEAR_MODEL_ARRAYS if k not in params]
    if lacking:
        raise MopError(
            f"{name} needs {', '.join(lacking)} in {data_path} (a linear model: param_A, param_C, param_Q, "
            "param_R; optional param_B, param_P0, param_x0_mean), or write the file with mop simulate"
        )
    if has_inputs != ("B" in params):
        raise MopError(
            f"{data_path}: "
            + (
                "the inputs u need param_B (B, n, k), the input matrix of the linear model"
                if has_inputs
                else "param_B is given but there are no inputs u; add u (B, T+1, k) or drop param_B"
            )
        )
    tensors = {k: torch.from_numpy(v).double() for k, v in params.items()}
    model = LinearModelParams.from_arrays(tensors, by=name, where=str(data_path))
    linear_model_from_params(model)  # shapes checked before any work
    return "", model


def write_simulation(
    path: Path, names: list[str], sims: list[np.ndarray], context: int, measured: list[np.ndarray]
) -> None:
    """The simulated outputs y_C.. (ysim, one (T - C, m) array per record) with the measured ones beside
    them (y; measured: each record's (T, m) outputs), so a plot or a score needs no other file."""
    if path.suffix == ".npz":
        if len({len(p) for p in sims}) != 1:
            raise MopError(f"{path}: trajectories differ in length; write a .csv instead")
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            y = np.stack([y[context:] for y in measured])
            np.savez(f, ysim=np.stack(sims), y=y, context=np.array(context))
        return
    m = sims[0].shape[-1]
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(SIMULATION_COLUMNS(m))
        for name, p, y in zip(names, sims, measured, strict=True):
            for j, row in enumerate(p):
                w.writerow(
                    [name, context + j, *[f"{v:.7g}" for v in y[context + j]], *[f"{v:.7g}" for v in row]]
                )


def SIMULATION_COLUMNS(m: int) -> list[str]:  # noqa: N802  (one layout for mop predict and mop benchmark)
    """The columns of a simulation CSV: trajectory, t, the measured y0.. and the simulated ysim0..."""
    return ["trajectory", "t", *[f"y{i}" for i in range(m)], *[f"ysim{i}" for i in range(m)]]


SIMULATION_HEADER = ("trajectory", "steps", "1-step rmse", "fit %", "sim rmse", "sim nrmse", "sim fit %")


def print_simulation_errors(names, data, yhat, sims, context: int) -> None:
    """Per trajectory and overall, over t >= C: one-step (yhat) beside free-run simulation: RMSE, NRMSE and
    fit % (mop.records.scores). A simulation that diverged (mop.records.divergence_step) scores RMSE inf
    and is named with its step; the overall row of any diverged one is inf too."""
    print("{:>12} {:>6} {:>12} {:>7} {:>12} {:>10} {:>10}".format(*SIMULATION_HEADER))
    rows, diverged = [], []
    for n, (y, _), p, s in zip(names, data, yhat, sims, strict=True):
        step = divergence_step(y, s)
        rows.append((n, y[context:], p[context:], s, step is not None))
        if step is not None:
            diverged.append(f"{n} at step {context + step}")
    rows.append(("overall", *[[r[i] for r in rows] for i in (1, 2, 3)], bool(diverged)))
    for name, y, p, s, blown in rows:
        one, sim = scores(y, p), scores(y, s)
        rmse, nrmse, fit = (math.inf, math.inf, -math.inf) if blown else (sim.rmse, sim.nrmse, sim.fit)
        print(
            f"{name:>12} {sim.steps:>6} {one.rmse:>12.4g} {one.fit:>7.2f} {rmse:>12.4g} "
            f"{nrmse:>10.4g} {fit:>10.2f}"
        )
    if diverged:
        print(
            f"diverged: the simulation of {', '.join(diverged)} left the measured range by over "
            f"{DIVERGENCE_FACTOR:g}x (or turned non-finite), so its sim rmse is inf, not a score over the "
            "steps before"
        )


def write_output(path: Path, names: list[str], yhat: list[np.ndarray]) -> None:
    if path.suffix == ".npz":
        if len({len(p) for p in yhat}) != 1:
            raise MopError(f"{path}: trajectories differ in length; write a .csv instead")
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            np.savez(f, yhat=np.stack(yhat))
    elif path.suffix == ".csv":
        m = yhat[0].shape[-1]
        steps = yhat[0].ndim == 3
        with atomic_path(path) as tmp, open(tmp, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["trajectory", "t", *(["j"] if steps else []), *[f"yhat{i}" for i in range(m)]])
            for name, p in zip(names, yhat, strict=True):
                for t, row in enumerate(p):
                    if not steps:
                        w.writerow([name, t, *[f"{v:.7g}" for v in row]])
                        continue
                    for j, r in enumerate(row[: len(p) - t]):
                        w.writerow([name, t, j, *[f"{v:.7g}" for v in r]])
    else:
        raise MopError(f"--out {path}: use a .csv or .npz file name")


def print_errors(names, data, yhat) -> None:
    """RMSE, NRMSE, fit % and mean ||e_t|| over t >= 1 (mop.records.scores), on the measured outputs only
    (missing ones, NaN, are skipped)."""
    print(f"{'trajectory':>12} {'steps':>6} {'rmse':>10} {'nrmse':>8} {'fit %':>7} {'mean|e|':>10}")
    rows = [(name, y[1:], p[1:]) for name, (y, _), p in zip(names, data, yhat, strict=True)]  # t=0: no data
    rows.append(("overall", [r[1] for r in rows], [r[2] for r in rows]))
    for name, y, p in rows:
        s = scores(y, p)
        print(f"{name:>12} {s.steps:>6} {s.rmse:>10.4g} {s.nrmse:>8.4g} {s.fit:>7.2f} {s.mean_norm:>10.4g}")


def print_horizon_errors(data, forecasts, steps: int) -> None:
    """Mean ||y_{t+j} - forecast[t, j]|| over trajectories and t >= 1 with t + j <= T, per k = j + 1."""
    print(f"{'k':>4} {'count':>8} {'mean|e|':>10}")
    for j in range(steps):
        pairs = [(y, f) for (y, _), f in zip(data, forecasts, strict=True) if len(y) - 1 > j]
        err = [y[1 + j :] - f[1 : len(y) - j, j] for y, f in pairs]  # t = 1..T-j
        e = np.concatenate([observed_norms(d) for d in err]) if err else np.zeros(0)
        print(f"{j + 1:>4} {len(e):>8} {e.mean() if len(e) else float('nan'):>10.4g}")


BYTES_PER_VALUE = 20  # the float32 tensor, its float64 copy and the float64 numpy array of each prediction


def check_predict_size(data, steps: int | None) -> None:
    """Refuse --steps beyond every trajectory's horizon, and an output that would not fit in memory."""
    longest = max(len(y) for y, _ in data) - 1  # T of the longest trajectory
    if steps is not None and steps > longest + 1:
        raise MopError(
            f"--steps {steps}: the longest trajectory has T = {longest} steps, so no forecast beyond "
            f"k = {longest + 1} has a target; use --steps <= {longest + 1}"
        )
    values = sum(len(y) for y, _ in data) * (steps or 1) * data[0][0].shape[-1]
    check_allocation(
        BYTES_PER_VALUE * values,
        f"predictions of {len(data)} trajectories" + (f" x {steps} steps" if steps else ""),
        "use fewer --steps or fewer trajectories per file",
    )


def simulation_context(simulate: int, data) -> int:
    """The context C of --simulate C; 0 (from the record's start) is C = 1: y_0 is the only output a
    simulation from the start can know, its initial condition (a state-space model estimates its initial
    state from it as its order allows), and y_1..y_T are simulated."""
    shortest = min(len(y) for y, _ in data) - 1
    if not 0 <= simulate <= shortest:
        raise MopError(f"--simulate must be in [0, {shortest}] (the shortest trajectory's T), got {simulate}")
    if simulate == 0:
        print("--simulate 0: simulated from each record's start, y_0 its initial condition (t >= 1 scored)")
    return max(simulate, 1)


def simulated_in_context(predictor, names, data, init: int, path: str) -> list[np.ndarray]:
    """Each test record simulated after the context file's last record (mop.incontext), with one line on
    how the context was used."""
    context = read_records(path)
    tests = [Record(y=y, u=u, name=n) for n, (y, u) in zip(names, data, strict=True)]
    for test in tests:
        check_context(test, context)  # every record checked before any simulation
    sims = []
    for test in tests:
        done = simulate_with_context(predictor, test, init, context)
        print(f"context {path} for {test.name}: {reading_line(done)}")
        sims.append(done.simulation)
    return sims


FIGURES = 4  # records drawn by mop predict --simulate (the first ones of the file)


def simulation_figures(
    out: Path, predictor: str, names, data, sims, context: int, sampling_time: float | None
) -> list[Path]:
    """OUT.png (one record) or OUT_NAME.png (the first FIGURES records): the simulation against the measured
    output, drawn as `mop benchmark` draws a test (mop.benchmarks.protocol.test_figure), the RMSE in the
    legend, time in seconds where the record gives its sampling time."""
    label = predictor.removeprefix("pretrained:").removeprefix("baseline:").rstrip("/") or "predictor"
    label = Path(label).name or label
    written = []
    for i, (name, (y, u), sim) in enumerate(zip(names, data, sims, strict=True)):
        if i == FIGURES:
            break
        record = Record(y=y, u=u, name=name, sampling_time=sampling_time, init_window=context)
        stem = out.stem if len(names) == 1 else f"{out.stem}_{re.sub(r'[^A-Za-z0-9._-]+', '-', name)}"
        written.append(test_figure(record, {label: sim}, "", out.parent, stem)[0])
    return written


def leak_warning(spec: str, predictor, data) -> str | None:
    """A warning where DATA holds the very samples the model was fitted or trained on (its fingerprint, or
    its run's training file): scores there measure the fit, not a prediction."""
    digest = fingerprint(data)
    info = getattr(predictor, "info", None)
    trained = isinstance(info, dict) and info.get("fingerprint") == digest
    if not trained and not is_pretrained(spec) and Path(spec, "config.json").is_file():
        data_config = load_config(spec).data
        path = Path(data_config.path if data_config is not None and data_config.path else "")
        if path.is_file() and path.suffix in (".csv", ".npz"):
            trained = fingerprint(read_timed(path)[1]) == digest
    if not trained:
        return None
    return (
        f"warning: these are the records {spec} was fitted on: the scores below measure the fit on its own "
        "data, not a prediction; score a record it never saw"
    )


def one_step_beside_simulation(predictor, data, family: str, params) -> list[np.ndarray]:
    """The one-step predictions shown beside a simulation of records with gaps; NaN (a blank column) where
    the predictor cannot read the gaps one step ahead (a fixed linear model), which the simulation does not
    need: it reads no output after its context."""
    try:
        return predict_all(predictor, data, None, family, params)
    except MopError as err:
        print(f"one-step column left blank: {err}")
        return [np.full_like(y, np.nan) for y, _ in data]


def default_output(data_path: Path, predictor: str) -> Path:
    """DATA_<predictor>_pred.csv beside the data: named after the predictor (a run or fitted directory's
    name, a shipped model's NAME, a baseline's name), so predicting one record with several predictors keeps
    every file."""
    name = predictor.split(":", 1)[1] if predictor.startswith("pretrained:") else Path(predictor).name
    name = re.sub(r"[^A-Za-z0-9._-]+", "-", name).strip("-.") or "predictor"
    return data_path.with_name(f"{data_path.stem}_{name}_pred{data_path.suffix}")


def run(args: argparse.Namespace) -> int:
    data_path = Path(args.data)
    if not data_path.is_file() or data_path.suffix not in (".csv", ".npz"):
        problem = (
            "is a folder"
            if data_path.is_dir()
            else "does not exist"
            if not data_path.exists()
            else "is not a .csv or .npz file"
        )
        raise MopError(f"data {data_path} {problem}; give a .csv or .npz file of trajectories")
    out = Path(args.out) if args.out else default_output(data_path, args.predictor)
    if out.suffix not in (".csv", ".npz"):
        raise MopError(f"--out {out}: use a .csv or .npz file name")
    if args.steps is not None and args.steps < 1:
        raise MopError(f"--steps must be >= 1, got {args.steps}")
    if args.simulate is not None and args.steps is not None:
        raise MopError("give --steps or --simulate, not both")
    if args.context is not None and args.simulate is None:
        raise MopError("--context FILE is read before a simulation: give --simulate C too")
    predictor, knows_system, what = resolve_predictor(args.predictor, args.stream)
    print(what)
    names, data, sampling_time = read_timed(data_path)
    check_predict_size(data, args.steps)
    leak = leak_warning(args.predictor, predictor, data)
    if leak:
        print(leak)
    context = None if args.simulate is None else simulation_context(args.simulate, data)
    has_inputs = data[0][1] is not None
    family, params = (
        system_of(args.predictor, data_path, len(data), has_inputs) if knows_system else ("", None)
    )
    if context is not None and any(np.isnan(y).any() for y, _ in data):
        yhat = one_step_beside_simulation(predictor, data, family, params)
        gaps = sum(int(np.isnan(y[context:]).any(axis=-1).sum()) for y, _ in data)
        if gaps:
            print(f"{gaps} step(s) after the context have missing outputs: simulated, left out of the scores")
    else:
        yhat = predict_all(predictor, data, args.steps, family, params)
    if context is not None:
        if args.context is not None:
            sims = simulated_in_context(predictor, names, data, context, args.context)
        else:
            sims = simulate_all(predictor, data, context, family, params)
        print_simulation_errors(names, data, yhat, sims, context)
        write_simulation(out, names, sims, context, [y for y, _ in data])
        figures = simulation_figures(out, args.predictor, names, data, sims, context, sampling_time)
        print(f"wrote {out}" + (f" and {', '.join(str(f) for f in figures)}" if figures else ""))
        return 0
    if args.steps is None:
        print_errors(names, data, yhat)
    else:
        print_horizon_errors(data, yhat, args.steps)
    write_output(out, names, yhat)
    print(f"wrote {out}")
    return 0
