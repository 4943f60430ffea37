"""`mop bench freerun`: wall time of `mop predict RUN TEST --simulate C` with a records model against the
same command with the fitted ARX (`mop fit arx`), side by side in one run.

Without --run / --arx it makes its own: a Duffing oscillator driven by a smoothed Gaussian input (seeded,
numpy: an estimation record of --est-steps and a test record of --steps samples), `mop train --data est.csv`
(the records recipe: a 1 x 32 transformer reading the fitted ARX feature; --train-steps steps, which
change the numbers but not the cost of a free run) and `mop fit arx est.csv`. Each command runs as a user
runs it (`python -m mop ...`, a fresh process, imports and file writing included), --repeats times,
alternating; the best wall time of each is reported and their ratio (the records model's over the ARX's).
--check N also runs the learned free run in process on the first N steps by the window path (one forward
per step) and by the default, and reports both times and the largest difference.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from mop.errors import MopError
from mop.identify.store import FILE as FITTED_FILE
from mop.models import simulate as sim
from mop.runs import load_predictor
from mop.systems import Trajectories


def duffing_record(steps: int, seed: int) -> np.ndarray:
    """(steps, 2) [y, u]: x'' = -0.3 x' - x - 0.5 x^3 + u, Euler steps of 0.1, y = x + N(0, 0.01^2)."""
    rng = np.random.default_rng(seed)
    u = np.convolve(rng.standard_normal(steps), np.ones(5) / 5, mode="same")
    x1 = x2 = 0.0
    y = np.empty(steps)
    for t in range(steps):
        y[t] = x1 + 0.01 * rng.standard_normal()
        x1, x2 = x1 + 0.1 * x2, x2 + 0.1 * (-0.3 * x2 - x1 - 0.5 * x1**3 + u[t])
    return np.stack([y, u], axis=1)


def write_record(path: Path, rows: np.ndarray) -> None:
    np.savetxt(path, rows, delimiter=",", header="y0,u0", comments="", fmt="%.8g")


def mop_command(*args: str) -> float:
    """Wall seconds of `python -m mop ARGS` (MopError with its last line if it fails)."""
    env = {**os.environ, "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "1")}
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "mop", *args], capture_output=True, text=True, env=env)
    seconds = time.perf_counter() - start
    if done.returncode:
        last = (done.stderr or done.stdout).strip().splitlines()[-1:]
        raise MopError(f"`mop {' '.join(args)}` failed: {last[0] if last else done.returncode}")
    return seconds


def in_process_check(run: str, test: Path, steps: int, context: int) -> dict[str, float]:
    """The learned free run on the first `steps` samples by the window path and by the default."""
    rows = np.loadtxt(test, delimiter=",", skiprows=1)[:steps]
    traj = Trajectories(torch.tensor(rows[None, :, :1]), torch.tensor(rows[None, :, 1:]))
    p = load_predictor(run)
    start = time.perf_counter()
    fast = sim.simulate(p, traj, context)
    fast_s = time.perf_counter() - start
    default = sim.slide_fast
    sim.slide_fast = lambda model: False  # the window path: one forward per simulated step
    try:
        start = time.perf_counter()
        slow = sim.simulate(p, traj, context)
        slow_s = time.perf_counter() - start
    finally:
        sim.slide_fast = default
    return {
        "steps": steps,
        "default_s": fast_s,
        "window_path_s": slow_s,
        "max_abs_diff": float((fast - slow).abs().max()),
    }


def measure(args: argparse.Namespace, work: Path) -> dict[str, object]:
    test = Path(args.data) if args.data else work / "test.csv"
    run, arx = args.run, args.arx
    if not args.data:
        write_record(test, duffing_record(args.steps, args.seed + 1))
    if run is None or arx is None:
        est = work / "est.csv"
        write_record(est, duffing_record(args.est_steps, args.seed))
        if run is None:
            run = str(work / "run")
            mop_command(
                "train", "--data", str(est), "--out", run, "--no-progress", f"train.steps={args.train_steps}"
            )
            # the bench times the network: where the run's held-out check kept a linear model
            # (mop.recipe.selection), `mop predict RUN` would load it instead
            (Path(run) / FITTED_FILE).unlink(missing_ok=True)
        if arx is None:
            arx = str(work / "arx")
            mop_command("fit", "arx", str(est), "--out", arx)
    if (Path(run) / FITTED_FILE).exists():
        raise MopError(
            f"{run} keeps a fitted linear model (its held-out check, {FITTED_FILE}), "
            "so `mop predict` would time that model: "
            "give a run that keeps its network"
        )
    times: dict[str, list[float]] = {"arx": [], "mop": []}
    for i in range(args.repeats):
        for name, source in (("arx", arx), ("mop", run)):
            out = work / f"{name}_{i}.csv"
            times[name].append(
                mop_command("predict", source, str(test), "--simulate", str(args.context), "--out", str(out))
            )
    best = {k: min(v) for k, v in times.items()}
    result: dict[str, object] = {
        "test": str(test),
        "samples": sum(1 for _ in open(test)) - 1,
        "context": args.context,
        "run": run,
        "arx": arx,
        "arx_s": best["arx"],
        "mop_s": best["mop"],
        "ratio": best["mop"] / best["arx"],
        "all_s": times,
    }
    if args.check:
        result["check"] = in_process_check(run, test, args.check, args.context)
    return result


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--run", help="a records model's run directory (default: train one on est.csv)")
    parser.add_argument("--arx", help="a `mop fit arx` directory (default: fit one on est.csv)")
    parser.add_argument("--data", help="the test record (default: a simulated Duffing record of --steps)")
    parser.add_argument("--steps", type=int, default=40_000, help="samples of the test record (40000)")
    parser.add_argument("--est-steps", type=int, default=4000, help="samples of the estimation record (4000)")
    parser.add_argument("--train-steps", type=int, default=100, help="records model training steps (100)")
    parser.add_argument("--context", type=int, default=50, help="--simulate C (50)")
    parser.add_argument("--repeats", type=int, default=1, help="runs of each command, best kept (1)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the simulated records (0)")
    parser.add_argument("--check", type=int, default=0, help="window path check on N steps (0)")


def run(args: argparse.Namespace) -> int:
    if args.steps <= args.context or args.context < 1 or args.repeats < 1 or args.train_steps < 1:
        raise MopError("need --context >= 1, --steps > --context, --repeats >= 1, --train-steps >= 1")
    if args.data and not Path(args.data).is_file():
        raise MopError(f"--data {args.data} does not exist")
    with tempfile.TemporaryDirectory(prefix="mop-freerun-") as tmp:
        r = measure(args, Path(tmp))
    if args.json:
        print(json.dumps(r, indent=2))
        return 0
    name = Path(str(r["test"])).name
    print(f"mop predict ... {name} --simulate {r['context']}: {r['samples']} samples, best of {args.repeats}")
    print(f"{'fitted ARX':>24} {r['arx_s']:8.2f} s")
    print(f"{'records model':>24} {r['mop_s']:8.2f} s   ({r['ratio']:.2f} x the ARX)")
    if "check" in r:
        c = r["check"]
        print(
            f"in process, first {c['steps']} steps: default {c['default_s']:.2f} s, window path "
            f"{c['window_path_s']:.2f} s, largest difference {c['max_abs_diff']:.2e}"
        )
    return 0
