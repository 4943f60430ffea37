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
--jobs N runs the work in N worker processes with one torch thread each (the small model's training gains
nothing from a second thread, so two jobs on two cores take about half the time): first every run the
(experiment, seed) units train, each a task of its own, the most work first; each unit as soon as its runs
are trained. A training's numbers depend on the thread count only through float rounding.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import json
import multiprocessing
from pathlib import Path

import torch

from mop.atomic import write_json, write_text
from mop.commands import OverridesAnywhere
from mop.config import RunConfig, from_dict, to_dict
from mop.errors import MopError
from mop.experiments import EXPERIMENTS, PRESETS, get_experiment
from mop.experiments.files import is_experiment_file, load_experiment
from mop.experiments.planning import planned_runs
from mop.experiments.runner import run_experiment
from mop.experiments.seeds import lead_table, seed_summary, seeds_table
from mop.experiments.validate import validate_experiment
from mop.predictors import PREDICTORS
from mop.train import train

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
    parser.add_argument(
        "--jobs",
        type=int,
        default=1,
        help="run experiments (and seeds) in N processes, one torch thread each (1: in this process)",
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
    if args.jobs < 1:
        raise MopError(f"--jobs must be at least 1, got {args.jobs}")
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
    units = [(exp, s) for exp in experiments for s in range(args.seed, args.seed + args.seeds)]
    common = dict(
        preset=preset, seed=args.seed, overrides=overrides, choices=chosen, pretrained=args.pretrained,
        wait=not args.no_wait, runs=args.runs, skip_missing=args.pretrained and args.experiment == "all",
    )  # fmt: skip
    outs = {
        exp.name: root / exp.name if (args.experiment == "all" or not args.out) else root
        for exp in experiments
    }
    if args.jobs == 1:
        done = [_unit(exp, s, outs[exp.name], args.seeds, not args.quiet, **common) for exp, s in units]
    else:
        spec = args.experiment if is_experiment_file(args.experiment) else None  # files reload (plugins)
        done = _in_workers(units, outs, args.jobs, args.seeds, spec, common)
    rows = []
    for exp in experiments:
        evals = {s: result for (e, s), result in zip(units, done, strict=True) if e is exp and result}
        if not evals:
            continue
        out = outs[exp.name]
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


def _one_thread() -> None:
    torch.set_num_threads(1)


def shared_runs(runs: str | None, out: Path) -> Path:
    """The directory of the trained runs: --runs, else OUT/../runs (one rule for the units and the planner,
    so the runs --jobs trains ahead are the ones the units look for)."""
    return Path(runs) if runs else out.parent / "runs"


def training_cost(config: RunConfig) -> float:
    """A training's work in arbitrary units, to start the longest first: steps x tokens x a transformer
    layer's multiply-adds per token (12 d^2 in the projections and MLP, 2 d per attended position)."""
    m, t = config.model, config.train
    return (
        t.steps
        * t.batch_size
        * t.horizon
        * m.num_layers
        * m.width
        * (12 * m.width + 2 * min(t.horizon, m.context))
    )


def _in_workers(units: list, outs: dict, jobs: int, num_seeds: int, spec: str | None, common: dict) -> list:
    """Every unit's eval.json (or None), computed in `jobs` spawned workers of one torch thread each.

    The runs the units train are trained first, as tasks of their own, the most work first (training_cost),
    so a unit that trains several (calibration, scaling) spreads over the workers. A unit is started once
    all its runs are finished, ahead of any training still waiting, so the long evaluations overlap the
    trainings. The first failure stops every task not yet started."""
    needs, plans = [], {}
    for exp, s in units:
        runs_dir = shared_runs(common["runs"], outs[exp.name])
        planned = [] if common["pretrained"] else planned_runs(
            exp, common["preset"], seed=common["seed"], train_seed=s, runs_dir=runs_dir,
            overrides=common["overrides"], choices=common["choices"],
        )  # fmt: skip
        mine = {run for config, run in planned if not (Path(run) / "done.json").is_file()}
        plans.update({run: config for config, run in planned if run in mine})
        needs.append(mine)
    trainings = sorted(plans, key=lambda run: -training_cost(plans[run]))
    results: list = [None] * len(units)
    waiting, trained, running = list(range(len(units))), set(), {}
    context = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(jobs, mp_context=context, initializer=_one_thread) as pool:
        try:
            while waiting or running:
                while len(running) < jobs and (task := next_task(waiting, needs, trained, trainings)):
                    kind, key = task
                    if kind == "unit":
                        exp, s = units[key]
                        future = pool.submit(
                            _unit, spec or exp.name, s, outs[exp.name], num_seeds, False, **common
                        )
                    else:
                        future = pool.submit(_train_run, spec, to_dict(plans[key]), key, common["wait"])
                    running[future] = task
                if not running:  # cannot happen: every run a unit needs is in `trainings` until trained
                    raise RuntimeError(f"units {waiting} wait for runs nobody trains")
                finished, _ = concurrent.futures.wait(running, return_when=concurrent.futures.FIRST_COMPLETED)
                for future in finished:
                    kind, key = running.pop(future)
                    value = future.result()
                    if kind == "run":
                        trained.add(key)
                    else:
                        results[key] = value
        except BaseException:  # the first failure stops the tasks not yet started
            pool.shutdown(wait=True, cancel_futures=True)
            raise
    return results


def next_task(
    waiting: list[int], needs: list[set[str]], trained: set[str], trainings: list[str]
) -> tuple[str, int | str] | None:
    """The next task to start, taken off its list: ("unit", i) for the first waiting unit i whose runs
    (needs[i]) are all trained, else ("run", the next of `trainings`), else None (nothing can start yet)."""
    ready = [i for i in waiting if needs[i] <= trained]
    if ready:
        waiting.remove(ready[0])
        return "unit", ready[0]
    return ("run", trainings.pop(0)) if trainings else None


def _train_run(spec: str | None, config: dict, run: str, wait: bool) -> None:
    """Train one run in a worker (the experiment file is loaded first: its plugins define the config)."""
    if spec:
        load_experiment(spec)
    train(from_dict(RunConfig, config), run, progress=False, wait=wait)


def _unit(
    exp,
    train_seed: int,
    out: Path,
    num_seeds: int,
    progress: bool,
    *,
    preset: str,
    seed: int,
    overrides: list[str],
    choices: dict[str, bool],
    pretrained: bool,
    wait: bool,
    runs: str | None,
    skip_missing: bool,
) -> dict | None:
    """One (experiment, training seed): run it into out (or out/seed-<s>) and hand back its eval.json, or
    None where `all --pretrained` has no shipped model for it (skip_missing). exp: an Experiment, or in a
    worker process its name or experiment file (reloaded there, with its plugins)."""
    if isinstance(exp, str):
        exp = load_experiment(exp) if is_experiment_file(exp) else get_experiment(exp)
    seed_out = out if num_seeds == 1 else out / f"seed-{train_seed}"
    try:
        report = run_experiment(
            exp,
            preset,
            seed_out,
            seed=seed,
            train_seed=train_seed,
            runs_dir=shared_runs(runs, out),
            overrides=overrides,
            progress=progress,
            choices=choices,
            pretrained=pretrained,
            wait=wait,
        )
    except MopError as err:
        if not (skip_missing and "no pretrained model" in str(err)):
            raise
        print(f"mop reproduce {exp.name}: skipped ({err})", flush=True)  # raised before any work
        return None
    suffix = ", pretrained" if pretrained else f", seed {train_seed}"
    data = json.loads((seed_out / "eval.json").read_text())
    features = data.get("settings", {}).get("features", "")  # what model.features=auto chose, with the steps
    suffix += f", features {features}" if features else ""
    print(f"mop reproduce {exp.name} ({preset}{suffix}): report at {report}", flush=True)
    return data
