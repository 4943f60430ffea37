"""`mop train [EXPERIMENT | FILE.toml | CONFIG.json] [--preset P] [--data FILE [--val FILE]] [--out DIR]
[key=value ...]`: train. The layers of the config are mop.recipe.layers' (later wins): a preset (the
CPU preset "small" where no GPU is present), an experiment under it or a RunConfig file < --data / --val < on
recorded data with inputs the ARX feature < dotted key=value overrides (e.g. train.steps=200).
"""

from __future__ import annotations

import argparse

from mop.commands import OverridesAnywhere
from mop.experiments.presets import PRESETS
from mop.recipe.budget import check_budget, check_minutes
from mop.recipe.fit import fine_tune_record, fit_record
from mop.recipe.given import read_given
from mop.train.device import distributed_session

EPILOG = """examples:
  mop train --out runs/linear                        # the linear family: CPU preset small, GPU paper
  mop train --preset paper --out runs/paper           # the paper's config (12 x 256, 10000 steps)
  mop train --out runs/tiny train.steps=200 model.num_layers=2 model.width=64 model.num_heads=4
  mop train config.json --out runs/x train.seed=1     # a JSON RunConfig, then overrides
  mop train linear --preset small --out runs/lin      # an experiment of mop.experiments
  mop train examples/rlc_circuit.toml --out runs/rlc  # an experiment file, as mop reproduce reads it
  mop train --data record.csv --out runs/mine         # one long record: its last 10% validates
  mop train --data est.csv --val val.csv --out runs/mine   # an estimation and a validation record
  mop train --data record.csv --init pretrained:lti-siso --out runs/ft   # fine-tune a class model
  mop train --data record.csv --budget 10 --max-minutes 30 --out runs/mine   # stop (resumable) after 30 min
  mop predict runs/mine new_runs.csv                             # predictions in the data's units
  torchrun --nproc_per_node 4 -m mop train --out runs/ddp        # DistributedDataParallel, rank 0 writes
  python -c "import mop; p = mop.load('runs/tiny'); print(p.name)"
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.__class__ = OverridesAnywhere
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.epilog = EPILOG
    parser.add_argument(
        "source", nargs="?", help="an experiment name or file (.toml), or a RunConfig .json (optional)"
    )
    parser.add_argument("overrides", nargs="*", metavar="key=value", help="dotted RunConfig overrides")
    parser.add_argument(
        "--preset",
        choices=tuple(PRESETS),
        default=None,
        help="model and training size (default: paper with a GPU, else small)",
    )
    parser.add_argument("--out", default="runs/mop", help="run directory (runs/mop)")
    parser.add_argument(
        "--data",
        default=None,
        help="train on recorded trajectories: .npz (y (B,T+1,m), optional u) or the CSV of `mop predict`; "
        "data.validation_fraction (0.1) is held out: whole trajectories where there are enough, else the "
        "last steps of each; channels normalised on the training part",
    )
    parser.add_argument("--val", default=None, help="a validation record for --data (all of --data trains)")
    parser.add_argument(
        "--init",
        default=None,
        metavar="RUN",
        help="fine-tune: start from this run directory's or pretrained:NAME's weights, with its model and "
        "normalisation, 125 steps at a tenth of its learning rate (key=value overrides win); a class "
        "model's ARX feature starts from the record's least-squares fit, its moments from the record's "
        "(model.record_prior_steps=100), a simulation model trains tails from step 1, and the run keeps "
        "its correction at the gain in 0..1 (or the better of the fitted ARX and N4SID) that simulates the "
        "record's held-out tail best",
    )
    parser.add_argument(
        "--budget",
        type=str,
        default=None,
        metavar="MINUTES",
        help="with --data and the records recipe: the steps MINUTES buy on a reference 2-core CPU (default "
        "5), at a nominal 20 ms a step of the recipe's 1 x 32 model (more for longer windows), at most 70 "
        "passes over the record, at least 1000 steps (mop.recipe.budget). The same steps, so the same "
        "weights, on every machine: the time they take here depends on this machine and its load (the plan "
        "line estimates it); --max-minutes limits the wall-clock time. A train.steps=N override wins",
    )
    parser.add_argument(
        "--max-minutes",
        type=str,
        default=None,
        metavar="MINUTES",
        help="a wall-clock limit for this command: training checkpoints and stops at the first step that "
        "ends past it, saying which step of how many; the run is usable as it stands (unfinished: mop.load "
        "warns) and the same command resumes it to the weights it would have had unstopped (the held-out "
        "check runs when it finishes). Not part of the run's config",
    )
    parser.add_argument(
        "--quiet", "--no-progress", dest="no_progress", action="store_true", help="no progress bar"
    )
    parser.add_argument(
        "--fresh",
        action="store_true",
        help="start over: remove the run's weights, checkpoint and metrics first (a damaged run)",
    )
    parser.add_argument(
        "--no-wait",
        action="store_true",
        help="if another process is training this --out, stop with an error instead of waiting for it",
    )


def run(args: argparse.Namespace) -> int:
    source, overrides = args.source, list(args.overrides or [])
    if source is not None and "=" in source:  # no config file: the first word is an override
        source, overrides = None, [source, *overrides]
    budget = None if args.budget is None else check_budget(args.budget)
    max_minutes = None if args.max_minutes is None else check_minutes(args.max_minutes, "--max-minutes")
    records = read_given(args.data, args.val)  # the record is read here, once; from here on it is in memory
    common = dict(
        source=source,
        preset=args.preset,
        overrides=overrides,
        budget=budget,
        progress=not args.no_progress,
        wait=not args.no_wait,
        fresh=args.fresh,
        announce=print,
        max_minutes=max_minutes,
    )
    with distributed_session():  # under torchrun: every rank closes the process group before it exits
        if args.init is None:
            fitted = fit_record(args.out, records, **common)
        else:
            fitted = fine_tune_record(args.out, records, args.init, **common)
    out = fitted.run_dir
    print(f"run directory: {out}  (load with: mop.load({str(out)!r}))")
    return 0
