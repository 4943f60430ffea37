"""`mop predict PREDICTOR DATA`: predictions yhat_t (of y_t from y_<t, u_<t) for measured or simulated
trajectories, by a trained run (PREDICTOR a run directory of `mop train`) or a registered predictor (a name).

Predictors that need only y (and u) run on any .csv or .npz (those registered with needs_system=False, e.g.
rls, last). Predictors that know the system (needs_system=True, e.g. kalman, ekf) read it from the `family`
string array and the `param_<name>` arrays of an .npz written by `mop simulate`.

Output: CSV long format `trajectory,t,yhat0..` or NPZ yhat (B, T+1, m) (all trajectories of one length).
With --steps K: k-step forecasts, forecast[t, j] predicting y_{t+j} from y_<t (j = 0..K-1, j = 0 the one-step
prediction; see mop.predictors.forecast): NPZ yhat (B, T+1, K, m) with NaN where t + j > T; CSV
`trajectory,t,j,yhat0..` with one row per (t, j), t + j <= T. Prints per-trajectory RMSE and mean ||e|| over
t >= 1 (one-step), or with --steps the mean ||y_{t+j} - forecast[t, j]|| per horizon k = j + 1 over t >= 1.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np
import torch

from mop.atomic import atomic_path
from mop.config import SystemConfig
from mop.errors import MopError
from mop.io import read_system, read_trajectories
from mop.predictors import PREDICTORS, forecast, is_learned, make_predictor, needs_system
from mop.runs import load_predictor
from mop.systems import FAMILIES
from mop.systems.base import Trajectories


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "predictor",
        help="run directory of `mop train`, or a registered predictor name; these need only the data: "
        + ", ".join(model_free()),
    )
    parser.add_argument("data", help="trajectories: .csv (trajectory,t,y0..,u0..) or .npz (y, u[, param_*])")
    parser.add_argument("--out", help="output .csv or .npz (default DATA stem + _pred)")
    parser.add_argument("--stream", action="store_true", help="KV-cache streaming (constant cost per step)")
    parser.add_argument("--steps", type=int, help="k-step forecasts for k = 1..STEPS (see above)")


def model_free() -> list[str]:
    """The registered predictors that need neither the system nor a run directory (from their metadata)."""
    return [n for n in PREDICTORS.names() if not needs_system(n) and not is_learned(n)]


def resolve_predictor(spec: str, stream: bool = False):
    """(predictor, needs_system) for a run directory or a registered (non-learned) predictor name."""
    if Path(spec).is_dir():
        return load_predictor(spec, mode="stream" if stream else "window"), False
    names = PREDICTORS.names()
    if spec not in names:
        raise MopError(
            f"{spec!r}: run directory {spec} does not exist and no predictor is registered under that name; "
            f"give a run directory or one of: {', '.join(sorted(names))}"
        )
    if is_learned(spec):
        raise MopError(f"{spec} is a learned predictor: give its run directory (mop train --out DIR)")
    return make_predictor(spec), needs_system(spec)


def system_of(name: str, data_path: Path, num: int) -> tuple[str, dict[str, torch.Tensor]]:
    """The family and params a system-aware predictor needs from DATA, or a one-line MopError."""
    if data_path.suffix == ".csv":
        raise MopError(
            f"{name} needs the system's parameters, and a CSV has no system parameters; "
            f"give an .npz written by mop simulate, or use {', '.join(model_free())}"
        )
    family, params = read_system(data_path, num)
    if not family:
        raise MopError(f"{name} needs the array family in {data_path}; write the file with mop simulate")
    if family not in FAMILIES.names():
        raise MopError(f"{data_path}: family {family!r} is not one of {', '.join(FAMILIES.names())}")
    sample = FAMILIES.get(family)(SystemConfig(family=family)).sample(1, generator=torch.Generator())
    missing = [f"param_{k}" for k in sample if k not in params]
    if missing:
        raise MopError(f"{name} needs {', '.join(missing)} in {data_path}; write the file with mop simulate")
    return family, {k: torch.from_numpy(v) for k, v in params.items()}


def batches(data, family: str, params: dict) -> list[Trajectories]:
    """One Trajectories of all trajectories when they share a length (and the system's parameters), else one
    per trajectory."""
    if len({len(y) for y, _ in data}) == 1:
        y = torch.tensor(np.stack([y for y, _ in data]), dtype=torch.float32)
        u = None if data[0][1] is None else torch.tensor(np.stack([u for _, u in data]), dtype=torch.float32)
        return [Trajectories(y=y, u=u, params=params, family=family)]
    return [
        Trajectories(
            y=torch.tensor(y[None], dtype=torch.float32),
            u=None if u is None else torch.tensor(u[None], dtype=torch.float32),
        )
        for y, u in data
    ]


def predict_all(predictor, data, steps: int | None = None, family: str = "", params=None) -> list[np.ndarray]:
    """[(T_i+1, m)] predictions (or [(T_i+1, K, m)] forecasts with steps), batched where lengths agree."""
    out = []
    for traj in batches(data, family, params or {}):
        pred = predictor.predict(traj) if steps is None else forecast(predictor, traj, steps)
        out += list(pred.double().cpu().numpy())
    return out


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


def observed_norms(e: np.ndarray) -> np.ndarray:
    """||e_t|| over the measured channels (e NaN where y was missing) for the steps with any measured:
    e (T, m) -> (T',)."""
    seen = ~np.isnan(e).all(axis=-1)
    return np.sqrt(np.nansum(e[seen] ** 2, axis=-1))


def print_errors(names, data, yhat) -> None:
    """RMSE and mean ||e_t|| over t >= 1, on the measured outputs only (missing ones, NaN, are skipped)."""
    print(f"{'trajectory':>12} {'steps':>6} {'rmse':>10} {'mean|e|':>10}")
    errs = []
    for name, (y, _), p in zip(names, data, yhat, strict=True):
        e = y[1:] - p[1:]  # (T, m), skip t=0 (no data)
        errs.append(e)
        print(f"{name:>12} {len(e):>6} {np.sqrt(np.nanmean(e**2)):>10.4g} {observed_norms(e).mean():>10.4g}")
    e = np.concatenate(errs)
    print(f"{'overall':>12} {len(e):>6} {np.sqrt(np.nanmean(e**2)):>10.4g} {observed_norms(e).mean():>10.4g}")


def print_horizon_errors(data, forecasts, steps: int) -> None:
    """Mean ||y_{t+j} - forecast[t, j]|| over trajectories and t >= 1 with t + j <= T, per k = j + 1."""
    print(f"{'k':>4} {'count':>8} {'mean|e|':>10}")
    for j in range(steps):
        err = [y[1 + j :] - f[1 : len(y) - j, j] for (y, _), f in zip(data, forecasts, strict=True)]
        e = np.concatenate([observed_norms(d) for d in err])
        print(f"{j + 1:>4} {len(e):>8} {e.mean() if len(e) else float('nan'):>10.4g}")


def run(args: argparse.Namespace) -> int:
    data_path = Path(args.data)
    out = Path(args.out) if args.out else data_path.with_name(data_path.stem + "_pred" + data_path.suffix)
    if out.suffix not in (".csv", ".npz"):
        raise MopError(f"--out {out}: use a .csv or .npz file name")
    if args.steps is not None and args.steps < 1:
        raise MopError(f"--steps must be >= 1, got {args.steps}")
    predictor, knows_system = resolve_predictor(args.predictor, args.stream)
    names, data = read_trajectories(data_path)
    family, params = system_of(args.predictor, data_path, len(data)) if knows_system else ("", {})
    yhat = predict_all(predictor, data, args.steps, family, params)
    if args.steps is None:
        print_errors(names, data, yhat)
    else:
        print_horizon_errors(data, yhat, args.steps)
    write_output(out, names, yhat)
    print(f"wrote {out}")
    return 0
