"""Your own systems, end to end: record, train with `mop train --data`, forecast with `mop predict`, compare.

    python examples/recorded_data.py [--out DIR] [--budget smoke|full] [--seed S]

1. Record. A tiny numpy simulator stands in for your lab: damped pendulums (the equations of
   examples/pendulum.py, integrated semi-implicitly), each recording from its own random system (length,
   damping, torque gain, sensor matrix C), driven by a random torque that is *not* recorded, with process and
   sensor noise, of 40 to 80 steps. The sensors report in their own units (100 x the pendulum's outputs).
   mop's simulators are never used: all mop sees is two CSV files in the long format of `mop predict`
   (trajectory,t,y0,y1): DIR/train.csv and DIR/heldout.csv (other systems, never seen in training).
2. Train. `mop train --data DIR/train.csv --out DIR/run key=value ...`: a seeded 10% of the recordings is held
   out for the validation loss, per-channel normalisation is fitted on the rest and saved in the run, so the
   run predicts in the sensors' units. Recordings shorter than train.horizon + 1 steps are skipped (counted).
3. Forecast and compare. `mop predict PREDICTOR DIR/heldout.csv --steps 10 --out DIR/forecasts/NAME.csv` for
   the trained run and for RLS (`rls`, matrix AR(2) fitted online), N4SID + Kalman filter (`n4sid-kf`,
   subspace identification from the prefix) and `last` (repeat y_{t-1}). Row (t, j) of a forecast file
   predicts y_{t+j} from y_0..y_{t-1}; k = j + 1 steps ahead. All four see the same outputs and nothing else.
   The table: mean ||y_{t+j} - forecast[t, j]|| (sensor units) over every held-out recording and every
   origin 20 <= t <= T - 9 (the same origins for every k), printed and written to DIR/heldout_errors.csv and
   DIR/heldout_errors.md.

Budgets: smoke (seconds; a tiny model, for the test suite; its numbers mean little) and full (2 layers of
width 64, horizon 40, 2000 steps on the 1800 training recordings; 136 s on a 2-core CPU, 70 s of it training).
Measured with the full budget, seed 0 (100 held-out pendulums, 3207 origins per k; the sensor noise alone
gives ~12.5):

    k  1: MOP 17.4, rls 19.6, n4sid-kf 19.1, last 24.7
    k  5: MOP 24.2, rls 33.4, n4sid-kf 29.4, last 65.5
    k 10: MOP 26.7, rls 37.2, n4sid-kf 32.6, last 87.3
If you record inputs (a torque you applied), add columns u0.. to the CSV: the run reads them, while rls,
n4sid-kf and last use outputs only.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import shlex
import sys
import time
from pathlib import Path

import numpy as np

from mop.cli import main as mop

TAU, GRAVITY = 0.1, 9.81  # as examples/pendulum.py
SENSOR_SCALE = 100.0  # the sensors' units: 100 x the pendulum's outputs
STEPS = 10  # forecast horizons k = 1..STEPS
FIRST_ORIGIN = 20  # table origins t >= 20: every predictor has had 20 outputs to adapt
PREDICTORS = {"MOP": None, "rls": "rls", "n4sid-kf": "n4sid-kf", "last": "last"}  # None: the trained run

BUDGETS = {
    "smoke": {
        "train_systems": 64,
        "heldout_systems": 6,
        "train": [
            "model.num_layers=1",
            "model.width=32",
            "model.num_heads=2",
            "model.context=20",
            "train.horizon=20",
            "train.batch_size=32",
            "train.steps=150",
            "train.lr=3e-3",
            "train.log_every=50",
            "train.checkpoint_every=150",
        ],
    },
    "full": {
        "train_systems": 2000,
        "heldout_systems": 100,
        "train": [
            "model.num_layers=2",
            "model.width=64",
            "model.num_heads=4",
            "model.context=40",
            "train.horizon=40",
            "train.batch_size=64",
            "train.steps=2000",
            "train.lr=3e-3",
            "train.lr_schedule=cosine",
            "train.warmup_steps=100",
            "train.checkpoint_every=500",
        ],
    },
}
COMMON = ["train.device=cpu", "train.compile=off", "train.seed=0"]


# ----------------------------------------------------------------------------------------------- 1. record


def record_pendulums(
    num: int, rng: np.random.Generator, min_len: int = 40, max_len: int = 80
) -> list[np.ndarray]:
    """`num` recordings y (T_i+1, 2) in sensor units, each of its own random pendulum, T_i+1 in [min, max].

    omega' = omega + tau (-(g/l) sin theta - b omega + k u),  theta' = theta + tau omega'   (then + w)
    y = SENSOR_SCALE (C x + v); l ~ U[0.5, 2], b ~ U[0.1, 0.5], k ~ U[0.5, 2], C ~ U[0, 1]^(2x2),
    u ~ U[-1, 1] (not recorded), w ~ N(0, 1e-3 I), v ~ N(0, 1e-2 I), x_0 ~ N(0, 0.25 I).
    Semi-implicit Euler (theta moves with the new omega): examples/pendulum.py's explicit step gains energy
    (its linearisation has determinant 1 - tau b + tau^2 g / l > 1), so its pendulums swing up and spin.
    """
    length, damping, gain = (rng.uniform(lo, hi, num) for lo, hi in ((0.5, 2), (0.1, 0.5), (0.5, 2)))
    C = rng.uniform(0, 1, (num, 2, 2))
    x = rng.normal(0, 0.5, (num, 2))  # (num, 2): theta, omega
    ys = []
    for _ in range(max_len):
        ys.append(np.einsum("bij,bj->bi", C, x) + rng.normal(0, 0.1, (num, 2)))
        theta, omega = x[:, 0], x[:, 1]
        u = rng.uniform(-1, 1, num)
        omega = omega + TAU * (-(GRAVITY / length) * np.sin(theta) - damping * omega + gain * u)
        x = np.stack([theta + TAU * omega, omega], axis=-1) + rng.normal(0, 1e-3**0.5, (num, 2))
    y = SENSOR_SCALE * np.stack(ys, axis=1)  # (num, max_len, 2)
    lengths = rng.integers(min_len, max_len + 1, num)
    return [y[i, : lengths[i]] for i in range(num)]


def write_csv(path: Path, recordings: list[np.ndarray], prefix: str) -> None:
    """The long format mop reads: trajectory,t,y0,y1 (one row per recording and time step)."""
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["trajectory", "t", "y0", "y1"])
        for i, y in enumerate(recordings):
            w.writerows([f"{prefix}{i}", t, f"{a:.6g}", f"{b:.6g}"] for t, (a, b) in enumerate(y))


def read_csv(path: Path, value_columns: int = 2, steps: bool = False) -> dict[str, np.ndarray]:
    """{trajectory: (T+1, m)} from a data CSV, or with `steps` {trajectory: (T+1, K, m)} (NaN where absent)
    from a `mop predict --steps K` CSV (trajectory,t,j,yhat0..)."""
    rows: dict[str, list[list[float]]] = {}
    with open(path, newline="") as f:
        reader = csv.reader(f)
        next(reader)
        for r in reader:
            rows.setdefault(r[0], []).append([float(v) for v in r[1:]])
    out = {}
    for name, table in rows.items():
        a = np.array(table)
        t = a[:, 0].astype(int)
        if not steps:
            out[name] = a[np.argsort(t), 1:]
            continue
        j = a[:, 1].astype(int)
        f = np.full((t.max() + 1, j.max() + 1, value_columns), np.nan)
        f[t, j] = a[:, 2:]
        out[name] = f
    return out


# ------------------------------------------------------------------------------------------ 2. and 3. mop


def run_mop(argv: list[str], log: Path | None = None) -> None:
    """One mop command, as you would type it; its printout goes to `log` when given."""
    print("$ mop " + shlex.join(argv), flush=True)
    with contextlib.ExitStack() as stack:
        if log is not None:
            stack.enter_context(contextlib.redirect_stdout(stack.enter_context(open(log, "w"))))
        code = mop(argv)
    if code != 0:
        raise SystemExit(f"mop {argv[0]} failed (exit {code})")


def error_table(data: dict[str, np.ndarray], forecasts: dict[str, dict[str, np.ndarray]]) -> list[dict]:
    """Rows {k, count, PREDICTOR: mean ||y_{t+k-1} - forecast[t, k-1]||} over origins 20 <= t <= T - 9."""
    rows = []
    for j in range(STEPS):
        row = {"k": j + 1}
        for name, fc in forecasts.items():
            errs = []
            for traj, y in data.items():
                t = np.arange(FIRST_ORIGIN, len(y) - STEPS + 1)  # origins whose 10-step target exists
                errs.append(np.linalg.norm(y[t + j] - fc[traj][t, j], axis=-1))
            e = np.concatenate(errs)
            row["count"], row[name] = len(e), float(e.mean())
        rows.append(row)
    return rows


def write_table(out: Path, rows: list[dict]) -> str:
    names = list(PREDICTORS)
    with open(out / "heldout_errors.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["k", "count", *names])
        w.writerows([r["k"], r["count"], *[f"{r[n]:.6g}" for n in names]] for r in rows)
    md = ["| k | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]
    md += [f"| {r['k']} | " + " | ".join(f"{r[n]:.3f}" for n in names) + " |" for r in rows]
    (out / "heldout_errors.md").write_text("\n".join(md) + "\n")
    lines = [f"{'k':>3} " + " ".join(f"{n:>9}" for n in names)]
    lines += [f"{r['k']:>3} " + " ".join(f"{r[n]:>9.3f}" for n in names) for r in rows]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=None, help="output directory (runs/recorded-BUDGET)")
    parser.add_argument("--budget", choices=BUDGETS, default="full")
    parser.add_argument("--seed", type=int, default=0, help="seed of the recordings")
    args = parser.parse_args(argv)
    budget = BUDGETS[args.budget]
    out = args.out or Path("runs") / f"recorded-{args.budget}"
    (out / "forecasts").mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()

    rng = np.random.default_rng(args.seed)
    train_csv, heldout_csv = out / "train.csv", out / "heldout.csv"
    write_csv(train_csv, record_pendulums(budget["train_systems"], rng), "train")
    write_csv(heldout_csv, record_pendulums(budget["heldout_systems"], rng), "heldout")  # other systems
    print(f"recorded {budget['train_systems']} + {budget['heldout_systems']} pendulums -> {out}")

    run_dir = out / "run"
    progress = ["--no-progress"] if args.budget == "smoke" else []
    run_mop(["train", "--data", str(train_csv), "--out", str(run_dir), *progress, *budget["train"], *COMMON])
    trained = time.perf_counter()

    forecasts = {}
    for name, spec in PREDICTORS.items():
        path = out / "forecasts" / f"{name}.csv"
        argv = ["predict", spec or str(run_dir), str(heldout_csv), "--steps", str(STEPS), "--out", str(path)]
        run_mop(argv, log=path.with_suffix(".log"))
        forecasts[name] = read_csv(path, steps=True)

    rows = error_table(read_csv(heldout_csv), forecasts)
    table = write_table(out, rows)
    done = time.perf_counter()
    print(
        f"\nheld-out recordings ({budget['heldout_systems']} unseen pendulums, sensor units): mean ||error|| "
        f"k steps ahead over origins {FIRST_ORIGIN} <= t <= T - {STEPS - 1} ({rows[0]['count']} per k)"
    )
    print(table)
    print(f"wall time: {done - start:.0f} s (training {trained - start:.0f} s); tables in {out}")
    return rows


if __name__ == "__main__":
    main(sys.argv[1:])
