"""Carry-over of a class model to single plants, as identification data comes: for each plant one estimation
and one validation record of 1024 steps, `mop fit arx` and `mop train --init SOURCE` (one fine-tune per
training seed) on the estimation record, then `mop predict RUN val.csv --simulate C` from several starts
C; prints the simulation RMSE over the simulated steps per plant, predictor and start, and writes them to
OUT/carry.json; with --report FILE also a markdown table of their means over plants and starts with its
provenance (the carry-over tables of docs/results/class-models.md are those files').

    python scripts/carry_over.py cascaded-tanks pretrained:cascaded-tanks OUT [--plants 1,5,3]
    python scripts/carry_over.py wiener-hammerstein pretrained:wiener-hammerstein OUT [--plants 1,2,3]
        [--seeds 0,1] [--starts 0,50,200] [--with zero-shot,scratch,n4sid,arx-best,last,source-orders]
        [--report FILE] [key=value ...]
        (key=value: overrides of the fine-tune)

--with adds predictors beside the fitted ARX and the fine-tunes: `zero-shot` (SOURCE on val.csv as it is),
`scratch` (`mop train --data est.csv model.arch=gpt`, the records recipe's transformer, the fine-tunes'
architecture, one run per training seed: the same network from scratch),
`n4sid` (`mop fit n4sid est.csv`), the online `arx-best` and `last`, which read only val.csv, and
`source-orders` (a second fine-tune per seed whose feature keeps the source's orders, model.rls_order=p
model.arx_order=q, where the default takes those `mop fit arx est.csv` chooses).

cascaded-tanks plants are examples/tank_records.py's (`--plant S`: input_amplitude 1.0, the plant drawn
with seed S): estimation and validation records are two experiments, their input and noise drawn with
seeds 10 S + 1 and 10 S + 2. Other families draw the plant with seed 1000 + S from their defaults, and
est.csv and val.csv are the two halves of one experiment of 2048 steps: those families normalise each
trajectory by its own mean and std, so two experiments of one plant would be in two sets of units.
Every run is one torch thread; the fine-tunes take 25-60 s each on a 2-core CPU.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
from pathlib import Path

import numpy as np
import torch

from mop.cli import main as mop
from mop.commands.benchmark import report_head
from mop.config import SystemConfig
from mop.records import scores
from mop.runs import load_config
from mop.systems import make_family

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
SAMPLES = 1024

# the scratch runs' architecture: the class models' (the records recipe's default is the deep LRU)
SCRATCH_ARCH = "model.arch=gpt"


def tank_records():
    spec = importlib.util.spec_from_file_location("tank_records", EXAMPLES / "tank_records.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def write_records(family_name: str, out: Path, plant: int) -> tuple[Path, Path]:
    """est.csv and val.csv of one plant of the family (tank_records' writer)."""
    records = tank_records()
    if family_name == "cascaded-tanks":
        return records.write_records(out, plant, SAMPLES)
    family = make_family(SystemConfig(family=family_name))
    params = family.sample(1, generator=torch.Generator().manual_seed(1000 + plant))
    return records.write_experiments(family, params, out, plant, SAMPLES, halves=True)


def run(argv: list[str]) -> None:
    print("$ mop " + " ".join(argv), flush=True)
    if mop(argv) != 0:
        raise SystemExit(f"mop {argv[0]} failed")


LABELS = {  # carry.json's predictor keys as the report names them (a trailing seed follows)
    "arx": "fitted ARX (`mop fit arx`)",
    "n4sid": "fitted N4SID (`mop fit n4sid`)",
    "zero-shot": "the class model as it is",
    "ft": "fine-tuned (`mop train --init {source}`), seed ",
    "fts": "fine-tuned with the source's orders, seed ",
    "scratch": "from scratch (`mop train --data model.arch=gpt`), seed ",
}


def report(results: dict[int, dict[str, list[float]]], args: argparse.Namespace) -> str:
    """One markdown table: per predictor the mean simulation RMSE over plants and starts, and how many of its
    simulations are below the fitted ARX's on the same plant and start."""
    names = list(next(iter(results.values())))
    total = sum(len(row["arx"]) for row in results.values())
    lines = report_head(
        f"Carry-over of {args.source} to single {args.family} plants",
        "python scripts/carry_over.py",
        f"Plants {args.plants}, simulations from steps {args.starts} of the validation record ({total} per "
        "predictor); simulation RMSE over the simulated steps.",
        ["predictor", "mean simulation RMSE", "simulations below the fitted ARX's"],
    )
    for name in names:
        runs = [pair for row in results.values() for pair in zip(row[name], row["arx"], strict=True)]
        mean = float(np.mean([rmse for rmse, _ in runs]))
        below = "-" if name == "arx" else f"{sum(rmse < arx for rmse, arx in runs)} of {len(runs)}"
        stem = name.rstrip("0123456789")
        label = LABELS.get(stem, f"`{stem}`").format(source=args.source) + name[len(stem) :]
        lines.append(f"| {label} | {mean:.4g} | {below} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("family")
    parser.add_argument("source")
    parser.add_argument("out", type=Path)
    parser.add_argument("--plants", default="1,2,3")
    parser.add_argument("--seeds", default="0")
    parser.add_argument("--starts", default="0,50,200")
    parser.add_argument(
        "--with", dest="extra", default="", help="zero-shot,scratch,n4sid,arx-best,last,source-orders"
    )
    parser.add_argument("--report", type=Path, default=None, help="also write the table as markdown here")
    parser.add_argument("overrides", nargs="*")
    args = parser.parse_intermixed_args()
    torch.set_num_threads(1)
    extra = [e for e in args.extra.split(",") if e]
    starts = [int(c) for c in args.starts.split(",")]
    source = load_config(args.source).model
    keys = [f"model.rls_order={source.rls_order}", f"model.arx_order={source.arx_order}"]  # source-orders
    results = {}
    for plant in (int(p) for p in args.plants.split(",")):
        d = args.out / f"plant{plant}"
        (d / "sim").mkdir(parents=True, exist_ok=True)
        est, val = write_records(args.family, d, plant)
        y = np.loadtxt(val, delimiter=",", skiprows=1, usecols=2)
        run(["fit", "arx", str(est), "--out", str(d / "arx")])
        runs = {"arx": str(d / "arx")}
        if "n4sid" in extra:
            run(["fit", "n4sid", str(est), "--out", str(d / "n4sid")])
            runs["n4sid"] = str(d / "n4sid")
        runs.update({name: name for name in ("arx-best", "last") if name in extra})
        if "zero-shot" in extra:
            runs["zero-shot"] = args.source
        for seed in (int(s) for s in args.seeds.split(",")):
            ft = d / f"ft{seed}"
            run(
                ["train", "--data", str(est), "--init", args.source, "--out", str(ft), f"train.seed={seed}"]
                + ["--no-progress", *args.overrides]
            )
            runs[f"ft{seed}"] = str(ft)
            if "source-orders" in extra:
                fts = d / f"fts{seed}"
                argv = ["train", "--data", str(est), "--init", args.source, "--out", str(fts)]
                run([*argv, f"train.seed={seed}", "--no-progress", *keys, *args.overrides])
                runs[f"fts{seed}"] = str(fts)
            if "scratch" in extra:
                scratch = d / f"scratch{seed}"
                argv = ["train", "--data", str(est), "--out", str(scratch), f"train.seed={seed}"]
                run([*argv, "--no-progress", SCRATCH_ARCH])
                runs[f"scratch{seed}"] = str(scratch)
        row = {}
        for name, path in runs.items():
            row[name] = []
            for c in starts:
                f = d / "sim" / f"{name}_{c}.npz"
                run(["predict", path, str(val), "--simulate", str(c), "--out", str(f)])
                ysim = np.load(f)["ysim"][0, :, 0]
                row[name].append(float(f"{scores(y[len(y) - len(ysim) :, None], ysim[:, None]).rmse:.4g}"))
        results[plant] = row
        print(f"plant {plant}, from steps {starts}: {row}", flush=True)
    (args.out / "carry.json").write_text(json.dumps(results, indent=1))
    if args.report is not None:
        args.report.write_text(report(results, args))


if __name__ == "__main__":
    main()
