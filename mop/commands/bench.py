"""`mop bench NAME`: each benchmark lives in mop/bench/<name>.py with add_arguments(parser) and run(args)."""

from __future__ import annotations

import argparse
import importlib

BENCHMARKS = {
    "simulate": "systems generated per second vs. a per-system loop",
    "filters": "KF, RLS and EKF over test systems vs. per-system loops (filterpy)",
    "train": "ms per training step vs. a plain Hugging Face GPT2Model loop",
    "stream": "streaming (KV cache) vs. window recomputation, predictions per second",
    "recipe": "MOP/KF MSE ratio reached within wall-clock budgets, training recipe vs. recipe",
    "forecast": "k-step forecast time against T and K beside one-step predict, learned model and filters",
    "predict": "one-step predict of long records per mode (window, stream, sliding): seconds and RMSE",
    "freerun": "mop predict --simulate wall time, records model vs. the fitted ARX, side by side",
    "features": "ms per training step of the small preset's model with the features auto picks vs. without",
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="benchmark", required=True, metavar="BENCHMARK")
    for name, help_text in BENCHMARKS.items():
        bench = sub.add_parser(name, help=help_text, description=help_text)
        importlib.import_module(f"mop.bench.{name}").add_arguments(bench)
        bench.add_argument("--json", action="store_true", help="print the result as one JSON object")


def run(args: argparse.Namespace) -> int:
    return importlib.import_module(f"mop.bench.{args.benchmark}").run(args)
