"""Running the units of `mop reproduce`: each (experiment, training seed) in this process, or all of them in
N worker processes with one torch thread each (`--jobs N`).

    done = run_units(units, outs, jobs=2, num_seeds=1, spec=None, settings=settings, report=print)

With N workers, every run the units train is trained first, each a task of its own, the most work first
(training_cost); each unit starts as soon as its runs are trained, ahead of any training still waiting, so
the long evaluations overlap the trainings. The small model's training gains nothing from a second thread,
so two jobs on two cores take about half the time. A training's numbers depend on the thread count only
through float rounding.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import json
import multiprocessing
from collections.abc import Callable
from pathlib import Path

import torch

from mop.config import RunConfig, from_dict, to_dict
from mop.errors import NoPretrainedModel
from mop.experiments import get_experiment
from mop.experiments.files import is_experiment_file, load_experiment
from mop.experiments.planning import planned_runs
from mop.experiments.runner import run_experiment
from mop.experiments.spec import Experiment
from mop.train import train

Unit = tuple[Experiment, int]  # (experiment, training seed)


@dataclasses.dataclass(frozen=True)
class UnitSettings:
    """What every unit of one `mop reproduce` shares: run_experiment's arguments, and
    skip_missing: a unit without a shipped model (NoPretrainedModel) is skipped, not an error."""

    preset: str
    seed: int
    overrides: list[str]
    choices: dict[str, bool]
    pretrained: bool = False
    wait: bool = True
    runs: str | None = None
    skip_missing: bool = False


@dataclasses.dataclass(frozen=True)
class UnitResult:
    """A finished unit: its eval.json (None where it was skipped) and the line that says so."""

    eval: dict | None
    message: str


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


def run_unit(
    exp: Experiment | str, train_seed: int, out: Path, num_seeds: int, progress: bool, settings: UnitSettings
) -> UnitResult:
    """One (experiment, training seed): run it into out (or out/seed-<s>) and hand back its eval.json, or
    None where `all --pretrained` has no shipped model for it (skip_missing). exp: an Experiment, or in a
    worker process its name or experiment file (reloaded there, with its plugins)."""
    if isinstance(exp, str):
        exp = load_experiment(exp) if is_experiment_file(exp) else get_experiment(exp)
    seed_out = out if num_seeds == 1 else out / f"seed-{train_seed}"
    s = settings
    try:
        report = run_experiment(
            exp, s.preset, seed_out, seed=s.seed, train_seed=train_seed, runs_dir=shared_runs(s.runs, out),
            overrides=s.overrides, progress=progress, choices=s.choices, pretrained=s.pretrained, wait=s.wait,
        )  # fmt: skip
    except NoPretrainedModel as err:
        if not s.skip_missing:
            raise
        return UnitResult(None, f"mop reproduce {exp.name}: skipped ({err})")  # raised before any work
    suffix = ", pretrained" if s.pretrained else f", seed {train_seed}"
    data = json.loads((seed_out / "eval.json").read_text())
    features = data.get("settings", {}).get("features", "")  # what model.features=auto chose, with the steps
    suffix += f", features {features}" if features else ""
    return UnitResult(data, f"mop reproduce {exp.name} ({s.preset}{suffix}): report at {report}")


def run_units(
    units: list[Unit],
    outs: dict[str, Path],
    *,
    jobs: int,
    num_seeds: int,
    spec: str | None,
    settings: UnitSettings,
    progress: bool = True,
    report: Callable[[str], None] = print,
) -> list[dict | None]:
    """Every unit's eval.json (None where skipped), in the units' order; `report` gets each unit's line
    as it finishes. outs: experiment name -> its output directory; spec: the experiment file the units
    come from (workers reload it, with its plugins), else None. jobs > 1: in worker processes."""
    if jobs > 1:
        return in_workers(units, outs, jobs, num_seeds, spec, settings, report)
    done = []
    for exp, s in units:
        result = run_unit(exp, s, outs[exp.name], num_seeds, progress, settings)
        report(result.message)
        done.append(result.eval)
    return done


def _trainings(units: list[Unit], outs: dict[str, Path], settings: UnitSettings):
    """(needs: per unit the unfinished runs it trains, plans: run -> RunConfig) of every unit."""
    needs, plans, c = [], {}, settings
    for exp, s in units:
        planned = [] if c.pretrained else planned_runs(
            exp, c.preset, seed=c.seed, train_seed=s, runs_dir=shared_runs(c.runs, outs[exp.name]),
            overrides=c.overrides, choices=c.choices,
        )  # fmt: skip
        mine = {run for config, run in planned if not (Path(run) / "done.json").is_file()}
        plans.update({run: config for config, run in planned if run in mine})
        needs.append(mine)
    return needs, plans


def in_workers(
    units: list[Unit],
    outs: dict[str, Path],
    jobs: int,
    num_seeds: int,
    spec: str | None,
    settings: UnitSettings,
    report: Callable[[str], None] = print,
) -> list[dict | None]:
    """Every unit's eval.json (or None), computed in `jobs` spawned workers of one torch thread each.

    The runs the units train are trained first, as tasks of their own, the most work first (training_cost),
    so a unit that trains several (calibration, scaling) spreads over the workers. A unit is started once
    all its runs are finished, ahead of any training still waiting, so the long evaluations overlap the
    trainings. The first failure stops every task not yet started."""
    needs, plans = _trainings(units, outs, settings)
    trainings = sorted(plans, key=lambda run: -training_cost(plans[run]))
    results: list = [None] * len(units)
    waiting, trained, running = list(range(len(units))), set(), {}
    context = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(jobs, mp_context=context, initializer=_one_thread) as pool:
        try:
            while waiting or running:
                while len(running) < jobs and (task := next_task(waiting, needs, trained, trainings)):
                    running[_submit(pool, task, units, outs, num_seeds, spec, settings, plans)] = task
                if not running:  # cannot happen: every run a unit needs is in `trainings` until trained
                    raise RuntimeError(f"units {waiting} wait for runs nobody trains")
                finished, _ = concurrent.futures.wait(running, return_when=concurrent.futures.FIRST_COMPLETED)
                for future in finished:
                    kind, key = running.pop(future)
                    value = future.result()
                    if kind == "run":
                        trained.add(key)
                    else:
                        report(value.message)
                        results[key] = value.eval
        except BaseException:  # the first failure stops the tasks not yet started
            pool.shutdown(wait=True, cancel_futures=True)
            raise
    return results


def _submit(pool, task, units, outs, num_seeds, spec, settings, plans) -> concurrent.futures.Future:
    """Start `task` ("unit", i) or ("run", run directory) in the pool."""
    kind, key = task
    if kind == "unit":
        exp, s = units[key]
        return pool.submit(run_unit, spec or exp.name, s, outs[exp.name], num_seeds, False, settings)
    return pool.submit(_train_run, spec, to_dict(plans[key]), key, settings.wait)


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


def _one_thread() -> None:
    torch.set_num_threads(1)


def _train_run(spec: str | None, config: dict, run: str, wait: bool) -> None:
    """Train one run in a worker (the experiment file is loaded first: its plugins define the config)."""
    if spec:
        load_experiment(spec)
    train(from_dict(RunConfig, config), run, progress=False, wait=wait)
