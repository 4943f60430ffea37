"""Recordings of systems driven by inputs, end to end: simulate them, train with `mop train --data`, compare
MOP with ARX, N4SID + Kalman filter and the last value on held-out recordings, one step ahead and in free-run
simulation.

    python examples/recordings_with_inputs.py [--out DIR] [--budget smoke|full] [--seed S]

1. Record. `mop simulate linear-inputs ...` writes DIR/train.npz and DIR/heldout.npz (other systems, another
   seed): x_{t+1} = A x_t + B u_t + w_t, y_t = C x_t + v_t with n = 4 states, m = 2 outputs and k = 1 known
   input u_t ~ N(0, 1) (u_t acts between y_t and y_{t+1}), T + 1 = 61 steps per recording. Only y and u are
   used for training; the held-out file also keeps the systems' matrices (param_A, ...), so the Kalman filter
   that knows each system (`kalman`) gives the optimum beside the others.
2. Train. `mop train --data DIR/train.npz --out DIR/run key=value ...`: per-channel normalisation of y and u
   fitted on the training split, a seeded 10% held out for the validation loss. The full budget turns on the
   ARX feature (model.rls_order=2 model.arx_order=2: the network reads the online ARX(2, 2) prediction and
   predicts its residual, so it starts as ARX and learns what ARX gets wrong).
3. Compare. For each predictor (the run, `arx`, `n4sid-kf`, `last`, `kalman`):
   `mop predict P DIR/heldout.npz --out DIR/onestep/P.npz` (yhat_t from y_<t, u_<t) and
   `mop predict P DIR/heldout.npz --simulate C --out DIR/simulation/P.npz` (y_C..y_T from y_<C and the inputs
   alone). The table (DIR/heldout_errors.md and .csv): RMSE of the one-step predictions over t in [20, T],
   and over t in [C, T] beside the simulation RMSE over the same steps (RMSE over steps, outputs and held-out
   recordings together, as `mop predict` prints its overall line).

Budgets: smoke (seconds; a tiny model trained for 30 steps, for the test suite: its MOP numbers mean little)
and full (2 layers of width 64, 4000 training recordings, 1500 steps; docs/results/families.md has its
numbers).
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

FAMILY = ["linear-inputs", "state_dim=4", "output_dim=2", "input_dim=1"]
HORIZON, CONTEXT, FIRST = 60, 40, 20  # T, the simulation's context C, the first step of the one-step window
PREDICTORS = {"MOP": None, "arx": "arx", "n4sid-kf": "n4sid-kf", "last": "last", "kalman": "kalman"}

BUDGETS = {
    "smoke": {
        "train_systems": 64,
        "heldout_systems": 8,
        "train": [
            "model.arch=gpt",  # the full budget's transformer (the records recipe's default is the deep LRU)
            "model.num_layers=1",
            "model.width=16",
            "model.num_heads=2",
            "train.batch_size=16",
            "train.steps=30",
            "train.lr=3e-3",
            "train.log_every=10",
            "train.checkpoint_every=30",
        ],
    },
    "full": {
        "train_systems": 4000,
        "heldout_systems": 200,
        "train": [
            "model.num_layers=2",
            "model.width=64",
            "model.num_heads=4",
            "model.rls_order=2",
            "model.arx_order=2",
            "train.batch_size=64",
            "train.steps=1500",
            "train.lr=3e-3",
            "train.lr_schedule=cosine",
            "train.warmup_steps=75",
            "train.checkpoint_every=500",
        ],
    },
}
COMMON = [
    f"model.context={HORIZON}",
    f"train.horizon={HORIZON}",
    "train.device=cpu",
    "train.compile=off",
    "train.seed=0",
]


def run_mop(argv: list[str], log: Path | None = None) -> None:
    """One mop command, as you would type it; its printout goes to `log` when given."""
    print("$ mop " + shlex.join(argv), flush=True)
    with contextlib.ExitStack() as stack:
        if log is not None:
            stack.enter_context(contextlib.redirect_stdout(stack.enter_context(open(log, "w"))))
        code = mop(argv)
    if code != 0:
        raise SystemExit(f"mop {argv[0]} failed (exit {code})")


def rmse(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e**2)))


def error_rows(y: np.ndarray, onestep: dict[str, np.ndarray], sims: dict[str, np.ndarray]) -> list[dict]:
    """One row per predictor: one-step RMSE over t in [FIRST, T], and over [C, T] beside the simulation's.
    y (B, T+1, m); onestep[name] yhat (B, T+1, m); sims[name] ysim (B, T+1-C, m)."""
    return [
        {
            "predictor": name,
            "one_step": rmse(onestep[name][:, FIRST:] - y[:, FIRST:]),
            "one_step_after_context": rmse(onestep[name][:, CONTEXT:] - y[:, CONTEXT:]),
            "simulation": rmse(sims[name] - y[:, CONTEXT:]),
        }
        for name in PREDICTORS
    ]


def write_table(out: Path, rows: list[dict]) -> str:
    keys = ["one_step", "one_step_after_context", "simulation"]
    with open(out / "heldout_errors.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["predictor", *keys])
        w.writerows([r["predictor"], *[f"{r[k]:.6g}" for k in keys]] for r in rows)
    T, C = HORIZON, CONTEXT
    head = (
        f"| predictor | one-step RMSE, t in [{FIRST}, {T}] | one-step RMSE, t in [{C}, {T}] "
        f"| simulation RMSE, t in [{C}, {T}] |"
    )
    md = [head, "|---|---|---|---|"]
    md += [f"| {r['predictor']} | " + " | ".join(f"{r[k]:.4f}" for k in keys) + " |" for r in rows]
    (out / "heldout_errors.md").write_text("\n".join(md) + "\n")
    return "\n".join(md)


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=None, help="output directory (runs/inputs-BUDGET)")
    parser.add_argument("--budget", choices=BUDGETS, default="full")
    parser.add_argument("--seed", type=int, default=0, help="seed of the training recordings (held out: +1)")
    args = parser.parse_args(argv)
    budget = BUDGETS[args.budget]
    out = args.out or Path("runs") / f"inputs-{args.budget}"
    for sub in ("onestep", "simulation"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()

    train, heldout = out / "train.npz", out / "heldout.npz"
    for path, num, seed in ((train, "train_systems", args.seed), (heldout, "heldout_systems", args.seed + 1)):
        run_mop(
            ["simulate", FAMILY[0], "--systems", str(budget[num]), "--horizon", str(HORIZON),
             "--seed", str(seed), "--out", str(path), *FAMILY[1:]],
            log=path.with_suffix(".log"),
        )  # fmt: skip

    run_dir = out / "run"
    run_mop(
        ["train", "--data", str(train), "--out", str(run_dir), "--no-progress", *budget["train"], *COMMON]
    )
    trained = time.perf_counter()

    onestep, sims = {}, {}
    for name, spec in PREDICTORS.items():
        predictor = spec or str(run_dir)
        one, sim = out / "onestep" / f"{name}.npz", out / "simulation" / f"{name}.npz"
        run_mop(["predict", predictor, str(heldout), "--out", str(one)], log=one.with_suffix(".log"))
        argv = ["predict", predictor, str(heldout), "--simulate", str(CONTEXT), "--out", str(sim)]
        run_mop(argv, log=sim.with_suffix(".log"))
        onestep[name], sims[name] = np.load(one)["yhat"], np.load(sim)["ysim"]

    rows = error_rows(np.load(heldout)["y"].astype(np.float64), onestep, sims)
    table = write_table(out, rows)
    done = time.perf_counter()
    print(f"\nheld-out recordings ({budget['heldout_systems']} unseen systems driven by inputs):\n{table}")
    print(f"wall time: {done - start:.0f} s (training {trained - start:.0f} s); tables in {out}")
    return rows


if __name__ == "__main__":
    main(sys.argv[1:])
