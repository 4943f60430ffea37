"""From a user's record to a trained run, in one sequence: the config (mop.recipe.layers), the training with
the recipe's hooks (mop.recipe.training), then the held-out choice (mop.recipe.selection).

`mop train` and mop.estimators.Learned both call fit_record, so a record trains the same way from the command
line and from Python; the command line hands it `print` to announce what it does.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Sequence
from pathlib import Path

from mop.config import RunConfig, parse_overrides
from mop.io import reading_once
from mop.recipe.budget import DEFAULT_BUDGET_MINUTES, check_minutes
from mop.recipe.finetune import records_start, within_budget
from mop.recipe.layers import gaps_turn_off_recipe, training_config
from mop.recipe.records import budget_plan, feature_line, order_line
from mop.recipe.selection import feature_alone, select_against_arx, selection_line, training_time
from mop.recipe.shrink import SHRINK_FILE, shrink_line
from mop.recipe.training import train
from mop.runs import load_config, read_run_json
from mop.train.data import validates_tails
from mop.train.loop import clock as loop_clock
from mop.train.records import recorded_data


@dataclasses.dataclass(frozen=True)
class FittedRun:
    """A finished run: its directory, the config it trained, and the held-out choice it made
    (mop.recipe.selection's result; None where the run makes none, or has not finished)."""

    run_dir: Path
    config: RunConfig
    selection: dict | None
    finished: bool = True  # False: stopped by max_minutes before its last step (resume by training again)


def selects(config: RunConfig) -> bool:
    """Whether the run makes the records recipe's held-out choice after training: a feature fitted on the
    record (model.rls_prior = "fit"), for a fine-tune too, unless train.shrink_correction chose its gain."""
    return config.data is not None and config.model.rls_prior == "fit" and not config.train.shrink_correction


def fit_record(
    out_dir: str | os.PathLike,
    data: str | None = None,
    val: str | None = None,
    *,
    source: str | None = None,
    preset: str | None = None,
    overrides: Sequence[str] = (),
    init: str | None = None,
    budget: float | None = None,
    fine_tune_minutes: float | None = None,
    progress: bool = True,
    wait: bool = True,
    fresh: bool = False,
    announce: Callable[[str], None] | None = None,
    max_minutes: float | None = None,
) -> FittedRun:
    """Train the run `out_dir` as `mop train [SOURCE] [--preset P] [--data DATA [--val VAL]] [--init RUN]
    [--budget MINUTES] [key=value ...]` does, reading the record once: its config (training_config), the
    training with the recipe's hooks, then, for a records recipe or a fine-tune with a fitted feature, the
    held-out choice between the network and the fitted ARX (select_against_arx).

    fine_tune_minutes: a fine-tune's train.steps cut to what these minutes allow at the measured time of one
    step (within_budget; machine-dependent), unless an override sets train.steps; for a records start
    (mop.recipe.finetune.records_start) the budget of the records recipe's plan instead.
    announce: given, it gets the lines `mop train` prints: the budget's plan, the record, its feature and
    orders before training; the loop's plan line; the held-out choice after it.
    max_minutes: a wall-clock limit from this call on (check_minutes): the training checkpoints and stops
    at the first step that ends past it, unfinished (FittedRun.finished False, no held-out choice yet;
    mop.load warns that it is unfinished); calling fit_record again resumes it, and the held-out choice is
    made when it finishes. The steps (and so the weights) do not depend on it.
    """
    deadline = (
        None if max_minutes is None else loop_clock() + 60 * check_minutes(max_minutes, "--max-minutes")
    )
    overrides = list(overrides)
    if init is not None and records_start(load_config(init)):  # the records recipe's budget plans its steps
        budget, fine_tune_minutes = (fine_tune_minutes if budget is None else budget), None
    with reading_once():  # the record is read once, whichever steps of the recipe look at it
        config = training_config(source, preset, data, val, overrides, init, budget)
        steps_given = "train.steps" in parse_overrides(overrides)
        if init is not None and fine_tune_minutes is not None and not steps_given:
            config = within_budget(config, fine_tune_minutes)
        if announce is not None:
            chosen = source is not None or preset is not None
            for line in record_lines(config, overrides, init, chosen, budget):
                announce(line)
        run_dir = train(
            config, out_dir, progress=progress, wait=wait, fresh=fresh, announce=announce, deadline=deadline
        )
        finished = (run_dir / "done.json").is_file()
        selection = select_against_arx(run_dir, config) if selects(config) and finished else None
    if announce is not None and not finished and selects(config):
        announce(
            "held-out check: not yet; it chooses between the network and the fitted ARX when the run finishes"
        )
    if announce is not None:
        if selection is not None:
            announce(selection_line(selection, feature_alone(config), training_time(run_dir)))
        shrunk = run_dir / SHRINK_FILE
        if config.train.shrink_correction and shrunk.is_file():
            announce(shrink_line(read_run_json(shrunk), config.data.path))
    return FittedRun(run_dir, config, selection, finished)


def record_lines(
    config: RunConfig, overrides: list[str], init: str | None, chosen: bool, budget: float | None
) -> list[str]:
    """What `mop train` says before training on a record: the records recipe's budget plan (where the plan
    set train.steps), the record, the feature, the orders and record_norm's prior."""
    lines = []
    if selects(config) and (init is None or records_start(load_config(init))):
        plan = budget_plan(config, DEFAULT_BUDGET_MINUTES if budget is None else budget)
        if plan.steps == config.train.steps:
            lines.append(plan.line())
    if config.data is None:
        return lines
    record = recorded_data(config.data)
    lines.append(record.summary(config.train.horizon, validates_tails(config)))
    if gaps_turn_off_recipe(config.data.path, overrides, chosen, init):
        m, t = config.model, config.train
        lines.append(
            f"records recipe: off: {config.data.path} has {record.num_missing} missing output(s), and the "
            "recipe's least-squares feature and its held-out check against `mop fit arx` need complete "
            f"outputs; this run trains the preset's {m.arch} {m.num_layers} x {m.width} model for "
            f"{t.steps} steps, with no --budget plan and no held-out check: fill the gaps to train with the "
            "records recipe, or size this run with model keys and train.steps=N"
        )
    lines.append(feature_line(config) or "feature: none (the network reads the record alone)")
    orders = order_line(config, overrides, init, chosen)
    if orders:
        lines.append(orders)
    if config.model.record_prior_steps:
        lines.append(
            f"record_norm: each record's running moments start from {config.model.record_prior_steps} "
            "steps at this record's mean and std (model.record_prior_steps), so it is read at the "
            "plant's scale from its first step"
        )
    return lines
