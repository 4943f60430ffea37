"""`mop train [EXPERIMENT_OR_CONFIG.json] [--preset P] [--data FILE] [--out DIR] [key=value ...]`: train.

Config layers, later wins: RunConfig defaults (the paper's) < a JSON config file or an experiment's preset
< --data FILE (sets data.path) < dotted key=value overrides (e.g. train.steps=200 model.num_layers=4,
data.validation_fraction=0.2).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import mop.experiments as experiments
from mop.commands import OverridesAnywhere
from mop.config import DataConfig, RunConfig, apply_overrides, from_dict
from mop.errors import MopError
from mop.train import train
from mop.train.data import recorded_data

EPILOG = """examples:
  mop train --out runs/linear                                   # the paper's config (10000 steps)
  mop train --out runs/tiny train.steps=200 model.num_layers=2 model.width=64 model.num_heads=4
  mop train config.json --out runs/x train.seed=1                # a JSON RunConfig, then overrides
  mop train linear --preset small --out runs/linear-small        # an experiment of mop.experiments
  mop train --data runs.npz --out runs/mine train.horizon=40     # recorded trajectories (.npz or .csv)
  mop predict runs/mine new_runs.csv                             # predictions in the data's units
  torchrun --nproc_per_node 4 -m mop train --out runs/ddp        # DistributedDataParallel, rank 0 writes
  python -c "import mop; p = mop.load('runs/tiny'); print(p.name)"
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.__class__ = OverridesAnywhere
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.epilog = EPILOG
    parser.add_argument("source", nargs="?", help="a RunConfig JSON file or an experiment name (optional)")
    parser.add_argument("overrides", nargs="*", metavar="key=value", help="dotted RunConfig overrides")
    parser.add_argument("--preset", default=None, help="preset of the experiment (paper|small|smoke)")
    parser.add_argument("--out", default="runs/mop", help="run directory (runs/mop)")
    parser.add_argument(
        "--data",
        default=None,
        help="train on recorded trajectories: .npz (y (B,T+1,m), optional u) or the CSV of `mop predict`; "
        "a seeded data.validation_fraction (0.1) is held out, channels normalised on the training split",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def base_config(source: str | None, preset: str | None) -> RunConfig:
    """Defaults, a JSON file, or an experiment's preset."""
    if source is None:
        if preset:
            raise MopError("--preset needs an experiment name, e.g. mop train linear --preset small")
        return RunConfig()
    path = Path(source)
    if path.suffix == ".json" or path.exists():
        if not path.is_file():
            raise MopError(f"config file {path} does not exist")
        try:
            data = json.loads(path.read_text())
        except json.JSONDecodeError as err:
            raise MopError(f"{path} is not valid JSON ({err.msg} at line {err.lineno})") from None
        return from_dict(RunConfig, data)
    return _experiment_config(source, preset)


def _experiment_config(name: str, preset: str | None) -> RunConfig:
    try:
        exp = experiments.get_experiment(name)
    except (ImportError, AttributeError):
        raise MopError(f"{name!r} is neither a config file nor a known experiment") from None
    preset = preset or "small"
    if hasattr(exp, "run_config"):
        return exp.run_config(preset)
    return experiments.run_config(exp, preset)


def run(args: argparse.Namespace) -> int:
    source, overrides = args.source, list(args.overrides or [])
    if source is not None and "=" in source:  # no config file: the first word is an override
        source, overrides = None, [source, *overrides]
    config = base_config(source, args.preset)
    if args.data is not None:
        data = config.data or DataConfig(path=args.data)
        config = dataclasses.replace(config, data=dataclasses.replace(data, path=args.data))
    config = apply_overrides(config, overrides)
    if config.data is not None:  # the trainer fits the normalisation afresh (a saved config's is refitted)
        unfitted = dict.fromkeys(("y_mean", "y_std", "u_mean", "u_std"))
        config = dataclasses.replace(config, data=dataclasses.replace(config.data, **unfitted))
        print(recorded_data(config.data).summary(config.train.horizon))
    out = train(config, args.out, progress=not args.no_progress)
    print(f"run directory: {out}  (load with: mop.load({str(out)!r}))")
    return 0
