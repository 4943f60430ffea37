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
--jobs N runs the work in N worker processes with one torch thread each (mop.experiments.schedule).
This module parses the arguments and prints; mop.experiments.reproduce does the work.
"""

from __future__ import annotations

import argparse

from mop.commands import OverridesAnywhere
from mop.experiments import EXPERIMENTS, PRESETS
from mop.experiments.reproduce import Reproduction, optional_predictors, reproduce

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
    experiments = ", ".join(EXPERIMENTS.names())
    parser.add_argument("experiment", help=f"an experiment ({experiments}), all, or a .toml/.json file")
    parser.add_argument("overrides", nargs="*", metavar="key=value", help="RunConfig overrides for every run")
    add = parser.add_argument
    add(
        "--preset",
        choices=list(PRESETS),
        default=None,
        help="paper (GPU default), small (CPU default), smoke",
    )
    add("--out", default=None, help="output directory (default runs/reproduce/PRESET/EXPERIMENT)")
    add("--runs", default=None, help="directory of the shared trained runs (default OUT/../runs)")
    add("--seed", type=int, default=0, help="training seed; test systems use seed + 7000001")
    add("--seeds", type=int, default=1, help="train K seeds S..S+K-1, report mean, range and CIs (1)")
    _add_predictor_choices(parser)
    add(
        "--pretrained",
        action="store_true",
        help="evaluate the shipped models (mop pretrained) instead of training (default preset: small)",
    )
    add(
        "--jobs",
        type=int,
        default=1,
        help="run experiments (and seeds) in N processes, one torch thread each (1: in this process)",
    )
    add("--quiet", action="store_true", help="no progress output")
    add(
        "--no-wait",
        action="store_true",
        help="if another process is training a run this needs, stop with an error instead of waiting",
    )


def _add_predictor_choices(parser: argparse.ArgumentParser) -> None:
    """--with / --without PREDICTOR, and --NAME / --no-NAME for each predictor some preset leaves out."""
    with_help = "also train and evaluate PREDICTOR where its preset leaves it out (repeatable)"
    parser.add_argument(
        "--with", dest="with_", action="append", default=[], metavar="PREDICTOR", help=with_help
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


def run(args: argparse.Namespace) -> int:
    reproduction = Reproduction(
        args.experiment,
        preset=args.preset,
        out=args.out,
        runs=args.runs,
        seed=args.seed,
        seeds=args.seeds,
        overrides=list(args.overrides or []),
        with_=list(args.with_),
        without=list(args.without),
        pretrained=args.pretrained,
        jobs=args.jobs,
        progress=not args.quiet,
        wait=not args.no_wait,
    )
    reproduce(reproduction, report=lambda line: print(line, flush=True))
    return 0
