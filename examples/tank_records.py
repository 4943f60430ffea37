"""A worked example as identification data comes: one estimation and one validation record of one plant with
hard nonlinearities (two cascaded tanks with square-root outflows and overflow), MOP trained on the estimation
record with mop's defaults beside the fitted ARX and N4SID and the online arx-best, on the validation record.

    python examples/tank_records.py [--out DIR] [--budget smoke|full] [--seeds K] [--plant S]

1. Record. One plant of the "cascaded-tanks" family (mop/systems/cascaded_tanks.py, drawn with seed S, input
   swing input_amplitude=1.0 so that both tanks overflow at times), two multisine experiments of 1024 samples
   each (Ts = 4 s, as the benchmark's records): DIR/est.csv and DIR/val.csv (trajectory,t,y0,u0; y the lower
   tank's level in V, u the pump voltage).
2. Fit and train on est.csv only, every command with its defaults but MOP's architecture, the records
   recipe's transformer (model.arch=gpt; the recipe's default network is the deep LRU):
       mop train --data est.csv --out DIR/mop-S train.seed=S model.arch=gpt   (S = 0..K-1: training seeds)
       mop fit arx est.csv --out DIR/arx ;  mop fit n4sid est.csv --out DIR/n4sid
3. Compare on val.csv: `mop predict P val.csv` (one step ahead) and `mop predict P val.csv --simulate 50`
   (free run from the inputs alone after 50 outputs), P each of the above and the online `arx-best` and
   `last`. The table (DIR/validation.md and .csv): one-step RMSE over t >= 512 (the record's second half)
   and over t >= 50, simulation RMSE and fit % over t >= 50, in volts; MOP as the mean over the seeds with
   their range.

Budgets: smoke (seconds, for the test suite: a tiny model trained for a few steps, its numbers mean little)
and full (the defaults; docs/results/families.md has its numbers).
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
import torch

from mop.cli import main as mop
from mop.config import SystemConfig
from mop.records import scores
from mop.systems import make_family

CONTEXT = 50
MOP = "MOP (mop train --data est.csv model.arch=gpt)"
ARCH = "model.arch=gpt"  # the records recipe's transformer, which this example's results measured
BUDGETS = {  # (samples per record, training overrides)
    "smoke": (
        300,
        ["train.steps=4", "model.width=16", "train.batch_size=8", "train.horizon=20", "model.context=20"],
    ),
    "full": (1024, [ARCH]),
}
BASELINES = {
    "arx (fitted)": "arx",
    "n4sid (fitted)": "n4sid",
    "arx-best (online)": "arx-best",
    "last": "last",
}


def run_mop(argv: list[str], log: Path | None = None) -> None:
    """One mop command, as you would type it; its printout goes to `log` when given."""
    print("$ mop " + shlex.join(argv), flush=True)
    with contextlib.ExitStack() as stack:
        if log is not None:
            stack.enter_context(contextlib.redirect_stdout(stack.enter_context(open(log, "w"))))
        code = mop(argv)
    if code != 0:
        raise SystemExit(f"mop {argv[0]} failed (exit {code})")


def write_records(out: Path, plant: int, samples: int) -> tuple[Path, Path]:
    """est.csv and val.csv: two experiments of `samples` steps on the one plant drawn with seed `plant`."""
    family = make_family(SystemConfig(family="cascaded-tanks", input_amplitude=1.0))
    params = family.sample(1, generator=torch.Generator().manual_seed(plant))
    return write_experiments(family, params, out, plant, samples)


def write_experiments(
    family, params, out: Path, plant: int, samples: int, halves: bool = False
) -> tuple[Path, Path]:
    """est.csv and val.csv of `samples` steps each on the single system `params` of `family`: two
    experiments, their inputs and noise drawn with seeds 10 plant + 1 and 10 plant + 2; or with halves, the
    two halves of one experiment of 2 samples steps (seed 10 plant + 1), for a family that normalises each
    trajectory by its own mean and std (lti-siso, wiener-hammerstein): two experiments would put one plant
    in two sets of units, which no fitted model of est.csv can follow on val.csv."""
    if halves:
        seeded = torch.Generator().manual_seed(10 * plant + 1)
        traj = family.simulate(params, 2 * samples - 1, generator=seeded)
        parts = [("est", traj, 0), ("val", traj, samples)]
    else:
        parts = [
            (name, family.simulate(params, samples - 1, generator=torch.Generator().manual_seed(seed)), 0)
            for name, seed in (("est", 10 * plant + 1), ("val", 10 * plant + 2))
        ]
    paths = []
    for name, traj, start in parts:
        y, u = traj.y[0, start:, 0].double().numpy(), traj.u[0, start:, 0].double().numpy()
        path = out / f"{name}.csv"
        rows = [f"{name},{t},{float(y[t])!r},{float(u[t])!r}" for t in range(samples)]
        path.write_text("trajectory,t,y0,u0\n" + "\n".join(rows) + "\n")
        paths.append(path)
    return paths[0], paths[1]


def predictions(out: Path, predictor: str, val: Path, name: str) -> tuple[np.ndarray, np.ndarray]:
    """(one-step yhat (T+1,), simulation after CONTEXT (T+1-C,)) of `predictor` on the validation record."""
    one, sim = out / "onestep" / f"{name}.npz", out / "simulation" / f"{name}.npz"
    run_mop(["predict", predictor, str(val), "--out", str(one)], log=one.with_suffix(".log"))
    run_mop(
        ["predict", predictor, str(val), "--simulate", str(CONTEXT), "--out", str(sim)],
        log=sim.with_suffix(".log"),
    )
    return np.load(one)["yhat"][0, :, 0], np.load(sim)["ysim"][0, :, 0]


def row(y: np.ndarray, yhat: np.ndarray, ysim: np.ndarray) -> dict[str, float]:
    """The table's figures for one predictor (mop.records.scores, y and predictions (T+1,))."""
    sim, half = scores(y[CONTEXT:, None], ysim[:, None]), len(y) // 2
    return {
        "one_step_second_half": scores(y[half:, None], yhat[half:, None]).rmse,
        "one_step": scores(y[CONTEXT:, None], yhat[CONTEXT:, None]).rmse,
        "simulation": sim.rmse,
        "simulation_fit": sim.fit,
    }


KEYS = ["one_step_second_half", "one_step", "simulation", "simulation_fit"]
HEAD = (
    f"| predictor (fitted on est.csv) | one-step RMSE, second half | one-step RMSE, t >= {CONTEXT} "
    f"| simulation RMSE, t >= {CONTEXT} | simulation fit % |"
)


def write_table(out: Path, rows: dict[str, list[dict[str, float]]]) -> str:
    """Markdown and CSV; a predictor with several rows (training seeds) as mean [min, max]."""
    md = [HEAD, "|---|---|---|---|---|"]
    with open(out / "validation.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["predictor", "seed", *KEYS])
        for name, seeds in rows.items():
            w.writerows([name, s, *[f"{r[k]:.6g}" for k in KEYS]] for s, r in enumerate(seeds))
            cells = []
            for k in KEYS:
                v = np.array([r[k] for r in seeds])
                spread = f" [{v.min():.4g}, {v.max():.4g}]" if len(v) > 1 else ""
                cells.append(f"{v.mean():.4g}{spread}")
            md.append(f"| {name} | " + " | ".join(cells) + " |")
    (out / "validation.md").write_text("\n".join(md) + "\n")
    return "\n".join(md)


def main(argv: list[str] | None = None) -> dict[str, list[dict[str, float]]]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=None, help="output directory (runs/tanks-BUDGET)")
    parser.add_argument("--budget", choices=BUDGETS, default="full")
    parser.add_argument("--seeds", type=int, default=3, help="MOP training seeds 0..K-1 (3)")
    parser.add_argument("--plant", type=int, default=1, help="seed of the plant and its two records (1)")
    args = parser.parse_args(argv)
    out = args.out or Path("runs") / f"tanks-{args.budget}"
    for sub in ("onestep", "simulation"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    samples, overrides = BUDGETS[args.budget]
    est, val = write_records(out, args.plant, samples)
    y = np.loadtxt(val, delimiter=",", skiprows=1, usecols=2)
    rows: dict[str, list[dict[str, float]]] = {MOP: []}
    for seed in range(args.seeds):
        run = out / f"mop-{seed}"
        run_mop(
            [
                "train",
                "--data",
                str(est),
                "--out",
                str(run),
                "--no-progress",
                f"train.seed={seed}",
                *overrides,
            ]
        )
        rows[MOP].append(row(y, *predictions(out, str(run), val, f"mop-{seed}")))
    trained = time.perf_counter()
    for name, kind in BASELINES.items():
        spec = kind
        if kind in ("arx", "n4sid"):
            spec = str(out / kind)
            run_mop(["fit", kind, str(est), "--out", spec], log=out / f"fit-{kind}.log")
        rows[name] = [row(y, *predictions(out, spec, val, kind))]
    table = write_table(out, rows)
    print(
        f"\nvalidation record ({samples} samples, one plant of cascaded-tanks, seed {args.plant}):\n{table}"
    )
    print(
        f"wall time: {time.perf_counter() - start:.0f} s (MOP's trainings {trained - start:.0f} s); in {out}"
    )
    return rows


if __name__ == "__main__":
    main(sys.argv[1:])
