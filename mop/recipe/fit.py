"""From a user's record to a trained run, in one sequence: the config (mop.recipe.layers), the training with
the recipe's hooks (mop.recipe.training), then the held-out choice (mop.recipe.selection).

`mop train` and mop.estimators.Learned both call fit_record (from scratch) or fine_tune_record (--init), so a
record trains the same way from the command line and from Python; the command line hands it `print` to
announce what it does. The two share only their end (train_and_choose): a run from scratch never passes
the fine-tune's steps. Both read the record
before (`mop train --data FILE` once, at the command; Learned takes it in memory) and hand it in as
TrainingRecords: from here the recipe plans on it and the trainer trains on it, and no step reads it again.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Sequence
from pathlib import Path

from mop.config import RunConfig, parse_overrides
from mop.errors import MopError
from mop.models import reads_features
from mop.recipe.budget import DEFAULT_BUDGET_MINUTES, check_budget, check_minutes
from mop.recipe.feature_input import reads_feature_run, run_feature, save_feature, with_feature_run
from mop.recipe.finetune import fine_tune_config, records_start, within_budget
from mop.recipe.given import split
from mop.recipe.layers import scratch_config
from mop.recipe.plan import RECORDS_BODY
from mop.recipe.records import (
    body_line,
    budget_plan,
    feature_line,
    gaps_turn_off_recipe,
    order_line,
    recipe_reads,
)
from mop.recipe.selection import feature_alone, select_against_linear, selection_line, training_time
from mop.recipe.shrink import SHRINK_FILE, shrink_line
from mop.recipe.training import train
from mop.runs import load_config, read_run_json
from mop.train.data import validates_tails
from mop.train.loop import clock as loop_clock
from mop.train.records import RecordedData, TrainingRecords


@dataclasses.dataclass(frozen=True)
class FittedRun:
    """A finished run: its directory, the config it trained, and the held-out choice it made
    (mop.recipe.selection's result; None where the run makes none, or has not finished)."""

    run_dir: Path
    config: RunConfig
    selection: dict | None
    finished: bool = True  # False: stopped by max_minutes before its last step (resume by training again)


def selects(config: RunConfig, record: RecordedData | None = None) -> bool:
    """Whether the run makes the records recipe's held-out choice after training: a feature fitted on the
    record (model.rls_prior = "fit"), for a fine-tune too, unless train.shrink_correction chose its gain; or
    an architecture that reads no features (model.arch=deep-lru, gru) on a record (`record`, split) the linear
    models can be fitted on: inputs and complete outputs."""
    if config.data is None or config.train.shrink_correction:
        return False
    if config.model.rls_prior == "fit":
        return True
    featureless = not reads_features(config.model.arch)
    return featureless and record is not None and recipe_reads(record)


def fit_record(
    out_dir: str | os.PathLike,
    records: TrainingRecords | None = None,
    *,
    source: str | None = None,
    preset: str | None = None,
    overrides: Sequence[str] = (),
    budget: float | None = None,
    progress: bool = True,
    wait: bool = True,
    fresh: bool = False,
    announce: Callable[[str], None] | None = None,
    max_minutes: float | None = None,
) -> FittedRun:
    """Train the run `out_dir` from scratch as `mop train [SOURCE] [--preset P] [--data DATA [--val VAL]]
    [--budget MINUTES] [key=value ...]` does, in one downward sequence on one set of records in memory: its
    config and the records' split (mop.recipe.layers.scratch_config: the records recipe plans on that
    split), the training with the recipe's hooks, then, for a records recipe, the held-out choice between
    the network and the fitted linear models (select_against_linear). A fine-tune (--init) is
    fine_tune_record's.

    records: the records of --data (and --val) in memory, read by the caller (TrainingRecords.read at the
    command line; Learned takes them as given); None without --data.
    announce: given, it gets the lines `mop train` prints: the budget's plan, the record, its feature and
    orders before training; the loop's plan line; the held-out choice after it.
    max_minutes: a wall-clock limit from this call on (check_minutes): the training checkpoints and stops
    at the first step that ends past it, unfinished (FittedRun.finished False, no held-out choice yet;
    mop.load warns that it is unfinished); calling fit_record again resumes it, and the held-out choice is
    made when it finishes. The steps (and so the weights) do not depend on it.
    """
    deadline = _deadline(max_minutes)
    overrides = list(overrides)
    if budget is not None:  # before any file is read
        check_budget(budget)
    _in_memory(records)
    config, records, record = scratch_config(source, preset, records, overrides, budget)
    if announce is not None:
        chosen = source is not None or preset is not None
        for line in record_lines(config, record, records, overrides, None, chosen, budget):
            announce(line)
    return train_and_choose(config, out_dir, records, record, progress, wait, fresh, announce, deadline)


def fine_tune_record(
    out_dir: str | os.PathLike,
    records: TrainingRecords | None,
    init: str,
    *,
    source: str | None = None,
    preset: str | None = None,
    overrides: Sequence[str] = (),
    budget: float | None = None,
    fine_tune_minutes: float | None = None,
    progress: bool = True,
    wait: bool = True,
    fresh: bool = False,
    announce: Callable[[str], None] | None = None,
    max_minutes: float | None = None,
) -> FittedRun:
    """Fine-tune `init` (a run directory or pretrained:NAME) into the run `out_dir` as `mop train --data DATA
    --init SOURCE [key=value ...]` does: its config (mop.recipe.finetune.fine_tune_config), the training
    from the source's weights, then, with a fitted feature, the held-out choice; as fit_record otherwise.

    fine_tune_minutes: train.steps cut to what these minutes allow at the measured time of one step
    (within_budget; machine-dependent), unless an override sets train.steps; for a records start
    (mop.recipe.finetune.records_start) the budget of the records recipe's plan instead.
    """
    deadline = _deadline(max_minutes)
    overrides = list(overrides)
    if budget is not None:  # before any file is read
        check_budget(budget)
    if records_start(load_config(init)):  # the records recipe's budget plans its steps
        budget, fine_tune_minutes = (fine_tune_minutes if budget is None else budget), None
    _in_memory(records)
    config, records = fine_tune_config(source, preset, records, overrides, init, budget)
    if fine_tune_minutes is not None and "train.steps" not in parse_overrides(overrides):
        config = within_budget(config, fine_tune_minutes, records)
    record = split(config, records)  # the records split as the run trains on them
    if announce is not None:
        chosen = source is not None or preset is not None
        for line in record_lines(config, record, records, overrides, init, chosen, budget):
            announce(line)
    return train_and_choose(config, out_dir, records, record, progress, wait, fresh, announce, deadline)


def _deadline(max_minutes: float | None) -> float | None:
    """The loop clock's time at which a run of --max-minutes stops (None: no limit)."""
    return None if max_minutes is None else loop_clock() + 60 * check_minutes(max_minutes, "--max-minutes")


def _in_memory(records: TrainingRecords | None) -> None:
    if records is not None and not isinstance(records, TrainingRecords):
        raise MopError("fit_record takes the records in memory: give TrainingRecords.read(PATH), not a path")


def train_and_choose(
    config: RunConfig,
    out_dir: str | os.PathLike,
    records: TrainingRecords | None,
    record: RecordedData | None,
    progress: bool,
    wait: bool,
    fresh: bool,
    announce: Callable[[str], None] | None,
    deadline: float | None,
) -> FittedRun:
    """The training of `config` on `records` (mop.recipe.training.train), then the held-out choice on its
    split `record` where the run makes one (selects) and has finished, each announced where `announce`.
    With data.feature_input = "free-run" the network trains on the records with its feature's run
    (mop.recipe.feature_input), and the run holds that feature."""
    feature = run_feature(record) if reads_feature_run(config) else None
    if feature is not None:
        records = with_feature_run(records, feature)
    run_dir = train(
        config,
        out_dir,
        progress=progress,
        wait=wait,
        fresh=fresh,
        announce=announce,
        records=records,
        deadline=deadline,
    )
    if feature is not None:
        save_feature(run_dir, feature)
    finished = (run_dir / "done.json").is_file()
    chooses = selects(config, record)
    selection = select_against_linear(run_dir, config, record) if chooses and finished else None
    if announce is not None and not finished and chooses:
        announce(
            "held-out check: not yet; it chooses between the network and the fitted ARX and N4SID when the "
            "run finishes"
        )
    if announce is not None:
        if selection is not None:
            announce(selection_line(selection, feature_alone(config), training_time(run_dir)))
        shrunk = run_dir / SHRINK_FILE
        if config.train.shrink_correction and shrunk.is_file():
            announce(shrink_line(read_run_json(shrunk), config.data.path))
    return FittedRun(run_dir, config, selection, finished)


def record_lines(
    config: RunConfig,
    record: RecordedData | None,
    given: TrainingRecords | None,
    overrides: list[str],
    init: str | None,
    chosen: bool,
    budget: float | None,
) -> list[str]:
    """What `mop train` says before training on a record (`record`: config.data's records split as it asks,
    `given` the records in memory; None without data): the records recipe's budget plan (where the plan set
    train.steps), the record, the feature, the orders and record_norm's prior, or why the recipe is off."""
    lines = []
    if record is None:
        return lines
    if selects(config, record) and (init is None or records_start(load_config(init))):
        minutes = DEFAULT_BUDGET_MINUTES if budget is None else budget
        plan = budget_plan(record.training_part, config.train.batch_size, config.train.horizon, minutes)
        if plan.steps == config.train.steps:
            base = int(RECORDS_BODY["model.width"])  # the body's width, and what the budget's rest buys
            body = config.model.arch == RECORDS_BODY["model.arch"] and config.model.width == plan.width(base)
            lines.append(plan.line(base_width=base if body and init is None else None))
    lines.append(record.summary(config.train.horizon, validates_tails(config, record.given)))
    if gaps_turn_off_recipe(given, overrides, chosen, init):
        m, t = config.model, config.train
        lines.append(
            f"records recipe: off: {given.source} has {record.num_missing} missing output(s), and the "
            "recipe's least-squares feature and its held-out check against `mop fit arx` need complete "
            f"outputs; this run trains the preset's {m.arch} {m.num_layers} x {m.width} model for "
            f"{t.steps} steps, with no --budget plan and no held-out check: fill the gaps to train with the "
            "records recipe, or size this run with model keys and train.steps=N"
        )
    lines.append(feature_line(config) or "feature: none (the network reads the record alone)")
    body = body_line(config, overrides, init, chosen, record)
    if body:
        lines.append(body)
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
