"""mop reproduce EXPERIMENT|FILE [--preset paper|small|smoke] [--out DIR] [--seed S] [--seeds K] [key=value]

Train (or reuse), evaluate, report: one generic runner (mop.experiments.runner) for every experiment,
built in (mop.experiments.paper) or written as a TOML/JSON file. DIR holds eval.json, figures (PNG + PDF)
and report.md; trained runs live in DIR/../runs/<predictor>-<config hash> and are shared by every
experiment that trains the same config. `all` runs every registered experiment into DIR/<experiment>/.
key=value overrides change the training config of every run (e.g. train.steps=500 model.num_layers=2).
--seeds K trains K seeds (train.seed = S..S+K-1) on the same test systems (seed S) into DIR/seed-<s>/ and
writes DIR/seeds.md and seeds.json: every ratio's mean over seeds, range and each seed's bootstrap CI
(mop.experiments.seeds). `all` also writes DIR/summary.md: each experiment's MOP / best predictor ratio
beside the authors' number.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch

from mop.atomic import write_json, write_text
from mop.commands import OverridesAnywhere
from mop.errors import MopError
from mop.experiments import EXPERIMENTS, PRESETS, get_experiment
from mop.experiments.files import is_experiment_file, load_experiment
from mop.experiments.runner import run_experiment
from mop.experiments.seeds import lead_table, seed_summary, seeds_table
from mop.experiments.validate import validate_experiment
from mop.predictors import PREDICTORS

EPILOG = """examples:
  mop reproduce linear                                   # GPU: paper preset, else small
  mop reproduce linear --pretrained                      # the shipped model, no training: seconds
  mop reproduce all --preset smoke --out /tmp/all
  mop reproduce quadrotor --preset small train.steps=1000
  mop reproduce linear --preset small --with gru         # a baseline the preset leaves out
  mop reproduce examples/pendulum.toml --preset smoke     # an experiment file (plugins register a family)
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.__class__ = OverridesAnywhere
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.epilog = EPILOG
    parser.add_argument(
        "experiment", help=f"an experiment ({', '.join(EXPERIMENTS.names())}), all, or a .toml/.json file"
    )
    parser.add_argument("overrides", nargs="*", metavar="key=value", help="RunConfig overrides for every run")
    parser.add_argument(
        "--preset",
        choices=list(PRESETS),
        default=None,
        help="paper (GPU default), small (CPU default), smoke",
    )
    parser.add_argument(
        "--out", default=None, help="output directory (default runs/reproduce/PRESET/EXPERIMENT)"
    )
    parser.add_argument(
        "--runs", default=None, help="directory of the shared trained runs (default OUT/../runs)"
    )
    parser.add_argument("--seed", type=int, default=0, help="training seed; test systems use seed + 7000001")
    parser.add_argument(
        "--seeds", type=int, default=1, help="train K seeds S..S+K-1, report mean, range and CIs (1)"
    )
    parser.add_argument(
        "--with",
        dest="with_",
        action="append",
        default=[],
        metavar="PREDICTOR",
        help="also train and evaluate PREDICTOR where its preset leaves it out (repeatable)",
    )
    parser.add_argument(
        "--without", action="append", default=[], metavar="PREDICTOR", help="leave PREDICTOR out (repeatable)"
    )
    for name in optional_predictors():  # --NAME / --no-NAME: short for --with NAME / --without NAME
        parser.add_argument(
            f"--{name}", dest="with_", action="append_const", const=name, help="--with " + name
        )
        parser.add_argument(
            f"--no-{name}", dest="without", action="append_const", const=name, help="--without " + name
        )
    parser.add_argument(
        "--pretrained",
        action="store_true",
        help="evaluate the shipped models (mop pretrained) instead of training (default preset: small)",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress output")
    parser.add_argument(
        "--no-wait",
        action="store_true",
        help="if another process is training a run this needs, stop with an error instead of waiting",
    )


def optional_predictors() -> list[str]:
    """The predictors some preset leaves out (their registry metadata's skip_presets)."""
    return [name for name in PREDICTORS.names() if PREDICTORS.meta(name).get("skip_presets")]


def choices(args: argparse.Namespace) -> dict[str, bool]:
    """predictor -> in (True) or out (False), from --with / --without (a name in both: MopError)."""
    both = sorted(set(args.with_) & set(args.without))
    if both:
        raise MopError(f"--with and --without both name {', '.join(both)}; give one of them")
    return {**dict.fromkeys(args.with_, True), **dict.fromkeys(args.without, False)}


def run(args: argparse.Namespace) -> int:
    if args.seeds < 1:
        raise MopError(f"--seeds must be at least 1, got {args.seeds}")
    if args.pretrained and args.seeds > 1:
        raise MopError("--seeds K trains K seeds and --pretrained trains none; use one of them")
    default = "small" if args.pretrained else ("paper" if torch.cuda.is_available() else "small")
    preset = args.preset or default
    chosen = choices(args)
    if is_experiment_file(args.experiment):
        experiments = [load_experiment(args.experiment)]
    elif args.experiment == "all":
        experiments = [get_experiment(name) for name in EXPERIMENTS.names()]
    else:
        experiments = [get_experiment(args.experiment)]
    root = Path(args.out) if args.out else Path("runs/reproduce") / preset
    if args.pretrained:
        root = Path(args.out) if args.out else Path("runs/reproduce") / f"{preset}-pretrained"
    if args.pretrained:  # the optional baselines are not shipped: off unless asked for
        chosen = {**dict.fromkeys(optional_predictors(), False), **chosen}
    overrides = list(args.overrides or [])
    for exp in experiments:  # every mistake in any of them before the first training step
        validate_experiment(exp, preset, seed=args.seed, overrides=overrides, choices=chosen)
    rows = []
    for exp in experiments:
        out = root / exp.name if (args.experiment == "all" or not args.out) else root
        evals = {}
        for train_seed in range(args.seed, args.seed + args.seeds):
            seed_out = out if args.seeds == 1 else out / f"seed-{train_seed}"
            try:
                report = run_experiment(
                    exp,
                    preset,
                    seed_out,
                    seed=args.seed,
                    train_seed=train_seed,
                    runs_dir=Path(args.runs) if args.runs else (out.parent / "runs"),
                    overrides=overrides,
                    progress=not args.quiet,
                    choices=chosen,
                    pretrained=args.pretrained,
                    wait=not args.no_wait,
                )
            except MopError as err:
                if not (args.pretrained and args.experiment == "all" and "no pretrained model" in str(err)):
                    raise
                print(f"mop reproduce {exp.name}: skipped ({err})")  # raised before any work
                break
            evals[train_seed] = json.loads((seed_out / "eval.json").read_text())
            suffix = ", pretrained" if args.pretrained else f", seed {train_seed}"
            print(f"mop reproduce {exp.name} ({preset}{suffix}): report at {report}")
        if not evals:
            continue
        summary = seed_summary(evals)
        if args.seeds > 1:
            write_json(out / "seeds.json", summary)
            write_text(out / "seeds.md", seeds_table(exp.name, summary))
            print(f"mop reproduce {exp.name}: {args.seeds} seeds in {out / 'seeds.md'}")
        first = next(iter(summary.values()), {})
        rows.append({"experiment": exp.name, "best": first.get("best"), "authors": exp.authors})
    if args.experiment == "all":
        title = f"# mop reproduce all, preset {preset}, seeds {args.seed}..{args.seed + args.seeds - 1}\n\n"
        write_text(root / "summary.md", title + lead_table(rows))
        print(f"summary: {root / 'summary.md'}")
    return 0
