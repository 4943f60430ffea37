"""A class model in context on held-out systems of its class: each system's first --estimation steps are the
context (its estimation record), the next --test steps the test record, simulated from its first --init
outputs (mop.incontext). Prints, per model, the mean and median over systems of the free-run RMSE divided
by the test's output std for the readings "fit gain 0" (the least-squares ARX / NARX of the context alone),
"fit gain 1" (the model as trained) and the reading mop chooses on the context's held-out end; with --report
FILE also writes them as one markdown table with its provenance.

    python scripts/in_context_class.py FAMILY_MODEL MODEL [MODEL ...] [--systems 40] [--seed 2024]
        [--report FILE]

FAMILY_MODEL names the model (a run directory or pretrained:NAME) whose system section draws the systems.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from mop.commands.benchmark import report_head
from mop.incontext import _read, simulate_with_context
from mop.record import Record
from mop.runs import load_config, load_predictor
from mop.systems import generator, make_family


def report(summaries: list[dict], args: argparse.Namespace) -> str:
    """The summaries as one markdown table: a row per model, "mean (median)" per reading."""
    lines = report_head(
        f"Class models with an estimation record as context ({args.systems} systems)",
        "python scripts/in_context_class.py",
        f"Each system's first {args.estimation} steps are the context, the next {args.test} the test, "
        f"simulated from its first {args.init} outputs; free-run RMSE over the test's output std, mean "
        "(median) over systems.",
        ["model", "fit gain 0", "fit gain 1", "the reading mop chooses", "gain 1 below gain 0"],
    )
    for s in summaries:
        cells = [f"{s[k]['mean']:.3f} ({s[k]['median']:.3f})" for k in ("fit gain 0", "fit gain 1", "chosen")]
        below = f"{s['gain 1 / gain 0']['below 1']} of {s['systems']}"
        lines.append(f"| `{s['model']}` | " + " | ".join(cells) + f" | {below} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("family_model")
    parser.add_argument("models", nargs="+")
    parser.add_argument("--systems", type=int, default=40)
    parser.add_argument("--estimation", type=int, default=2000)
    parser.add_argument("--test", type=int, default=1000)
    parser.add_argument("--init", type=int, default=50)
    parser.add_argument("--seed", type=int, default=2024)
    parser.add_argument("--report", type=Path, default=None, help="also write the table as markdown here")
    args = parser.parse_args()
    torch.set_num_threads(1)
    family = make_family(load_config(args.family_model).system)
    steps = args.estimation + args.test - 1
    traj = family.generate(args.systems, steps, generator=generator(args.seed))
    records = [
        Record(y=traj.y[b].double().numpy(), u=traj.u[b].double().numpy()) for b in range(args.systems)
    ]
    summaries = []
    for path in args.models:
        predictor = load_predictor(path)
        scores: dict[str, list[float]] = {"fit gain 0": [], "fit gain 1": [], "chosen": []}
        for record in records:
            context, test = record[: args.estimation], record[args.estimation :]
            measured = test.y[args.init :]
            rmse = lambda sim, y=measured: float(np.sqrt(np.mean((sim - y) ** 2)) / y.std())  # noqa: E731
            for reading in ("fit gain 0", "fit gain 1"):
                scores[reading].append(rmse(_read(predictor, test, args.init, [context], reading)[0]))
            scores["chosen"].append(
                rmse(simulate_with_context(predictor, test, args.init, [context]).simulation)
            )
        ratio = np.array(scores["fit gain 1"]) / np.array(scores["fit gain 0"])
        summary = {
            k: {"mean": round(float(np.mean(v)), 5), "median": round(float(np.median(v)), 5)}
            for k, v in scores.items()
        }
        summary["gain 1 / gain 0"] = {
            "median": round(float(np.median(ratio)), 4),
            "below 1": int((ratio < 1).sum()),
        }
        summaries.append({"model": path, "systems": args.systems, **summary})
        print(json.dumps(summaries[-1]), flush=True)
    if args.report is not None:
        args.report.write_text(report(summaries, args))


if __name__ == "__main__":
    main()
