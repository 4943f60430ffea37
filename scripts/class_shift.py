"""Zero-shot class models on their own class and on neighbouring ones (distribution shift): every shipped SISO
class model, in context, on held-out systems of every class, beside the least-squares ARX, `arx-best`, `last`
and the filter that knows each system. Prints one table per data set and writes OUT/shift.json; with
--report FILE also one markdown table of them all with its provenance (the table "On other classes" of
docs/results/class-models.md is that file's).

    python scripts/class_shift.py OUT [--systems 100] [--seed 2026] [--report FILE]

Each data set is `mop simulate FAMILY --systems N --horizon 499 --seed S` (500 steps, systems no model trained
on); each predictor runs as `mop predict P data.npz` (one step ahead) and `mop predict P data.npz --simulate
400` (free run of y_400..y_499 from the inputs). Figures: each system's RMSE, averaged over the systems, one
step ahead over t >= 50 (Forgione et al.'s window) and in simulation. Every run is one torch thread.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from mop.cli import main as mop
from mop.commands.benchmark import report_head

CONTEXT = 400
HORIZON = 499
ONE_STEP_FROM = 50
MODELS = ("pretrained:lti-siso", "pretrained:wiener-hammerstein", "pretrained:cascaded-tanks")
BASELINES = ("arx-10-offset-ls", "arx-15-offset-ls", "arx-best", "last")
# name: (family, its settings, the filter that knows each system); the classes as the class experiments
# draw them (mop.experiments.classes), then two neighbours no model was trained on
DATA = {
    "lti-siso": ("lti-siso", ["max_abs=1e6"], "kalman"),
    "wiener-hammerstein": ("wiener-hammerstein", ["max_abs=1e6"], "ukf"),
    "cascaded-tanks": ("cascaded-tanks", ["max_abs=1e6", "input_amplitude=1.0"], "ukf"),
    "lti-siso, noisy (noise_std 0.1)": ("lti-siso", ["max_abs=1e6", "noise_std=0.1"], "kalman"),
    "cascaded-tanks, gentle (input_amplitude 0.4)": ("cascaded-tanks", ["max_abs=1e6"], "ukf"),
}


def run(argv: list[str]) -> None:
    print("$ mop " + " ".join(argv), flush=True)
    if mop(argv) != 0:
        raise SystemExit(f"mop {argv[0]} failed")


def rmse(y: np.ndarray, yhat: np.ndarray) -> float:
    """Each system's RMSE over the steps given, averaged over systems: y, yhat (N, steps, m)."""
    return float(np.sqrt(np.nanmean((y - yhat) ** 2, axis=(1, 2))).mean())


def report(results: dict[str, dict[str, dict[str, float]]], systems: int) -> str:
    """One markdown table: a row per data set, a column per predictor ("one-step / simulation"), the filter
    that knows each system last (named in its cell)."""
    names = [*MODELS, *BASELINES]
    head = ["data", *(f"`{n}`" for n in names), "the filter that knows each system"]
    lines = report_head(
        f"Class models on their own and neighbouring classes ({systems} systems each)",
        "python scripts/class_shift.py",
        f"Each system's RMSE, averaged: one step ahead over t >= {ONE_STEP_FROM} / simulation of "
        f"y_{CONTEXT}..y_{HORIZON} after {CONTEXT} outputs.",
        head,
    )
    for name, rows in results.items():
        cells = [f"{rows[n]['one_step']:.3g} / {rows[n]['simulation']:.3g}" for n in names]
        knowing = next(n for n in rows if n not in names)
        r = rows[knowing]
        cells.append(f"{r['one_step']:.3g} / {r['simulation']:.3g} (`{knowing}`)")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--systems", type=int, default=100)
    parser.add_argument("--seed", type=int, default=2026)
    parser.add_argument("--report", type=Path, default=None, help="also write the table as markdown here")
    args = parser.parse_args()
    torch.set_num_threads(1)
    args.out.mkdir(parents=True, exist_ok=True)
    results = {}
    for i, (name, (family, settings, knowing)) in enumerate(DATA.items()):
        data = args.out / f"data{i}.npz"
        seed = str(args.seed + i)
        run(["simulate", family, "--systems", str(args.systems), "--horizon", str(HORIZON), "--seed", seed,
             "--out", str(data), *settings])  # fmt: skip
        y = np.load(data)["y"]
        rows = {}
        for predictor in (*MODELS, *BASELINES, knowing):
            tag = predictor.replace("pretrained:", "")
            one, sim = args.out / f"data{i}_{tag}_1.npz", args.out / f"data{i}_{tag}_sim.npz"
            run(["predict", predictor, str(data), "--out", str(one)])
            run(["predict", predictor, str(data), "--simulate", str(CONTEXT), "--out", str(sim)])
            rows[predictor] = {
                "one_step": rmse(y[:, ONE_STEP_FROM:], np.load(one)["yhat"][:, ONE_STEP_FROM:]),
                "simulation": rmse(y[:, CONTEXT:], np.load(sim)["ysim"]),
            }
        results[name] = rows
        print(f"\n{name}: one-step RMSE over t >= {ONE_STEP_FROM} / simulation RMSE of y_{CONTEXT}..")
        for predictor, r in rows.items():
            print(f"  {predictor:32s} {r['one_step']:.4g} / {r['simulation']:.4g}", flush=True)
    (args.out / "shift.json").write_text(json.dumps(results, indent=1))
    if args.report is not None:
        args.report.write_text(report(results, args.systems))


if __name__ == "__main__":
    main()
