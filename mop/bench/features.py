"""`mop bench features`: ms per training step of the small preset's model, with and without its features.

What `model.features=auto` picks for --family (mop.train.auto) costs training steps: the small preset divides
its budget by the features' step cost (mop.train.auto.STEP_COST) so that a model with them trains as long as
the plain one. This measures that cost for a family, side by side in one process with one torch thread:

- plain: the small preset's model reading [y_t, u_t] alone;
- one Gaussian: auto's identifier started from the family's one-Gaussian prior (model.rls_prior=family), where
  auto took the mixture prior;
- auto: the features auto picks.

Each variant draws its own batches (TrainingData, seeded) and trains its own copy of the model; after
--warmup untimed steps each, --rounds rounds take 4 steps of every variant in turn, and each variant's time
is the median over rounds (so load that comes and goes falls on every variant alike). Plugin families
(--plugin FILE) are imported first.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import time
from pathlib import Path

import torch

from mop.config import RunConfig, SystemConfig, from_dict
from mop.errors import MopError
from mop.experiments.presets import get_preset
from mop.models import build_model
from mop.plugins import import_plugin
from mop.systems import FAMILIES
from mop.train.auto import FeatureChoice, describe_features, steps_for
from mop.train.data import TrainingData
from mop.train.optim import LossModule, make_optimizer, train_step
from mop.train.rundir import resolve_config

STEPS_PER_ROUND = 4


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--family", default=None, help="system family (the default family)")
    parser.add_argument(
        "--plugin", action="append", default=[], help="a family's Python file to import first (repeatable)"
    )
    parser.add_argument("--rounds", type=int, default=15, help="timed rounds of 4 steps per variant (15)")
    parser.add_argument("--warmup", type=int, default=3, help="untimed steps per variant first (3)")


def variants(family: str) -> dict[str, RunConfig]:
    """name -> resolved RunConfig: "plain", "one Gaussian" (where auto took the mixture prior), "auto"."""
    small = get_preset("small")
    system = from_dict(SystemConfig, {"family": family})
    auto = resolve_config(RunConfig(system=system, model=small.model, train=small.train))
    no_prior = dict(rls_prior="none", rls_prior_cov=None, rls_prior_weights=None, rls_prior_noise=0.0)
    plain = dataclasses.replace(
        auto.model, features="given", rls_order=0, arx_order=0, input_scale="none", **no_prior
    )
    found = {"plain": dataclasses.replace(auto, model=plain)}
    if auto.model.rls_prior_weights is not None:
        one = dataclasses.replace(auto.model, **{**no_prior, "rls_prior": "family"})
        found["one Gaussian"] = resolve_config(dataclasses.replace(auto, model=one))
    found["auto"] = auto
    return {name: _with_budget(config, small.train.steps) for name, config in found.items()}


def _with_budget(config: RunConfig, steps: int) -> RunConfig:
    """config with the steps the small preset's budget gives its features (mop.train.auto.steps_for)."""
    m = config.model
    features = FeatureChoice(
        scale=m.input_scale == "running",
        order=m.rls_order,
        input_order=m.arx_order,
        prior_weights=tuple(m.rls_prior_weights or ()),
    )
    return dataclasses.replace(
        config, train=dataclasses.replace(config.train, steps=steps_for(steps, features.cost))
    )


def measure(configs: dict[str, RunConfig], rounds: int, warmup: int) -> dict[str, float]:
    """name -> median ms per training step (module docstring), one torch thread."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    device = torch.device("cpu")
    try:
        runs = {}
        for name, config in configs.items():
            torch.manual_seed(config.train.seed)
            model = build_model(config.model)
            optimizer = make_optimizer(model, config.train, device)
            runs[name] = (model, LossModule(model), optimizer, TrainingData(config, device), config.train, [])
        for model, loss, optimizer, data, train, _ in runs.values():
            for _ in range(warmup):
                train_step(model, loss, optimizer, *data.batch(), train, device)
        for _ in range(rounds):
            for model, loss, optimizer, data, train, times in runs.values():
                start = time.perf_counter()
                for _ in range(STEPS_PER_ROUND):
                    train_step(model, loss, optimizer, *data.batch(), train, device)
                times.append((time.perf_counter() - start) / STEPS_PER_ROUND * 1e3)
        return {name: statistics.median(run[-1]) for name, run in runs.items()}
    finally:
        torch.set_num_threads(threads)


def run(args: argparse.Namespace) -> int:
    if args.rounds < 1 or args.warmup < 0:
        raise MopError("--rounds must be at least 1 and --warmup at least 0")
    for plugin in args.plugin:
        import_plugin(Path(plugin))
    family = args.family or FAMILIES.default()
    configs = variants(family)
    ms = measure(configs, args.rounds, args.warmup)
    rows = [
        {
            "variant": name,
            "features": describe_features(config.model),
            "steps": config.train.steps,  # what the small preset's budget gives these features
            "ms_per_step": ms[name],
            "cost_vs_plain": ms[name] / ms["plain"],
        }
        for name, config in configs.items()
    ]
    result = {"family": family, "threads": 1, "rounds": args.rounds, "variants": rows}
    if args.json:
        print(json.dumps(result))
        return 0
    print(f"{'variant':<14} {'ms/step':>8} {'x plain':>8} {'steps':>6}   features")
    for row in rows:
        name, ms, cost = row["variant"], row["ms_per_step"], row["cost_vs_plain"]
        print(f"{name:<14} {ms:>8.1f} {cost:>8.3f} {row['steps']:>6}   {row['features']}")
    return 0
