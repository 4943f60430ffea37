"""mop pretrained [list | show NAME | build [NAME ...]]: the predictors shipped inside the package.

`pretrained:NAME` loads one wherever a run directory is accepted (mop predict, mop.load, make_predictor,
experiment files); `mop reproduce EXPERIMENT --pretrained` evaluates them instead of training.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from mop.commands import OverridesAnywhere
from mop.errors import MopError
from mop.experiments.pretrained_build import build
from mop.pretrained import PREFIX, ROOT, dimensions, read_card, shipped_dir, shipped_names

EPILOG = """examples:
  mop pretrained                              # the shipped models, one line each, and their cards
  mop pretrained show linear                  # the card (CARD.md) of pretrained:linear
  mop pretrained build linear --threads 2     # retrain, measure and ship it again (the card's command)
  mop predict pretrained:linear data.csv
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.__class__ = OverridesAnywhere  # key=value may follow the options
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.epilog = EPILOG
    parser.add_argument("action", nargs="?", default="list", choices=("list", "show", "build"))
    parser.add_argument(
        "names", nargs="*", metavar="NAME|key=value", help="models (build: all when none); build overrides"
    )
    parser.set_defaults(overrides=[])
    parser.add_argument("--threads", type=int, default=2, help="build: torch threads (the card records it)")
    parser.add_argument(
        "--work", default="runs/pretrained-build", help="build: training runs (a finished one is reused)"
    )
    parser.add_argument("--out", default=None, help="build: where to ship (default: inside the package)")
    parser.add_argument("--preset", default=None, help="build: another preset than the catalog's (small)")
    parser.add_argument("--quiet", action="store_true", help="build: no progress output")


def summary_line(name: str, card: dict) -> str:
    ev = card["evaluation"]
    late = next(w for w in ev["ratio_to_reference"] if w.startswith("[20,"))
    r = ev["ratio_to_reference"][late]
    m, k = dimensions(card["model"])
    return (
        f"{PREFIX}{name}: m={m} outputs, k={k} inputs, class {card['family']['family']}, "
        f"{card['num_parameters']} params "
        f"({card['size_bytes'] / 1e3:.0f} kB); MOP/{ev['reference']} MSE t in {late} {r['ratio']:.3f} "
        f"[{r['low']:.3f}, {r['high']:.3f}] on {ev['num_systems']} systems. {card['summary']}"
    )


def list_models() -> int:
    names = shipped_names()
    if not names:
        print("no pretrained models are shipped; build them with `mop pretrained build`")
        return 0
    total = 0
    for name in names:
        card = read_card(name)
        total += card["size_bytes"]
        print(summary_line(name, card))
        print(f"    card: {shipped_dir(name) / 'CARD.md'}  (mop pretrained show {name})")
    print(f"{len(names)} models, {total / 1e6:.2f} MB of weights")
    return 0


def run(args: argparse.Namespace) -> int:
    names = [n for n in args.names if "=" not in n]
    overrides = [n for n in args.names if "=" in n] + list(args.overrides)
    if args.action == "list":
        return list_models()
    if args.action == "show":
        if len(names) != 1 or overrides:
            raise MopError("mop pretrained show takes one NAME, e.g. mop pretrained show linear")
        print((shipped_dir(names[0]) / "CARD.md").read_text(), end="")
        return 0
    if args.threads < 1:
        raise MopError(f"--threads must be >= 1, got {args.threads}")
    out = Path(args.out) if args.out else ROOT
    build(
        names,
        work=Path(args.work),
        out_root=out,
        threads=args.threads,
        overrides=overrides,
        preset=args.preset,
        progress=not args.quiet,
        report=print,
    )
    return 0
