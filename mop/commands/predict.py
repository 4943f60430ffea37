"""`mop predict RUN_DIR DATA`: one-step predictions yhat_t (of y_t from y_<t, u_<t) for measured trajectories.

Writes per trajectory and step the prediction (CSV long format `trajectory,t,yhat0..`, or NPZ yhat (B,T+1,m)
when all trajectories have one length) and prints per-trajectory RMSE and mean ||y_t - yhat_t|| over t >= 1.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np
import torch

from mop.atomic import atomic_path
from mop.errors import MopError
from mop.io import read_trajectories
from mop.systems.base import Trajectories


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run_dir", help="run directory of `mop train`")
    parser.add_argument("data", help="trajectories: .csv (trajectory,t,y0..,u0..) or .npz (y, u)")
    parser.add_argument("--out", help="output .csv or .npz (default DATA stem + _pred)")
    parser.add_argument("--stream", action="store_true", help="KV-cache streaming (constant cost per step)")


def predict_all(predictor, data) -> list[np.ndarray]:
    """[(T_i+1, m)] predictions, one forward per trajectory."""
    out = []
    for y, u in data:
        traj = Trajectories(
            y=torch.tensor(y[None], dtype=torch.float32),
            u=None if u is None else torch.tensor(u[None], dtype=torch.float32),
        )
        out.append(predictor.predict(traj)[0].double().numpy())
    return out


def write_output(path: Path, names: list[str], yhat: list[np.ndarray]) -> None:
    if path.suffix == ".npz":
        if len({len(p) for p in yhat}) != 1:
            raise MopError(f"{path}: trajectories differ in length; write a .csv instead")
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            np.savez(f, yhat=np.stack(yhat))
    elif path.suffix == ".csv":
        m = yhat[0].shape[1]
        with atomic_path(path) as tmp, open(tmp, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["trajectory", "t", *[f"yhat{i}" for i in range(m)]])
            for name, p in zip(names, yhat, strict=True):
                for t, row in enumerate(p):
                    w.writerow([name, t, *[f"{v:.7g}" for v in row]])
    else:
        raise MopError(f"--out {path}: use a .csv or .npz file name")


def run(args: argparse.Namespace) -> int:
    from mop.runs import load_predictor

    data_path = Path(args.data)
    out = Path(args.out) if args.out else data_path.with_name(data_path.stem + "_pred" + data_path.suffix)
    if out.suffix not in (".csv", ".npz"):
        raise MopError(f"--out {out}: use a .csv or .npz file name")
    predictor = load_predictor(args.run_dir, mode="stream" if args.stream else "window")
    names, data = read_trajectories(data_path)
    yhat = predict_all(predictor, data)
    print(f"{'trajectory':>12} {'steps':>6} {'rmse':>10} {'mean|e|':>10}")
    errs = []
    for name, (y, _), p in zip(names, data, yhat, strict=True):
        e = y[1:] - p[1:]  # (T, m), skip t=0 (no data)
        errs.append(e)
        print(
            f"{name:>12} {len(e):>6} {np.sqrt((e**2).mean()):>10.4g} "
            f"{np.linalg.norm(e, axis=-1).mean():>10.4g}"
        )
    e = np.concatenate(errs)
    print(
        f"{'overall':>12} {len(e):>6} {np.sqrt((e**2).mean()):>10.4g} "
        f"{np.linalg.norm(e, axis=-1).mean():>10.4g}"
    )
    write_output(out, names, yhat)
    print(f"wrote {out}")
    return 0
