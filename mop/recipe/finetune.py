"""The fine-tune recipe of `mop train --data FILE --init SOURCE` (a run directory or pretrained:NAME).

FINE_TUNE sets a short schedule before the overrides (with_fine_tuning); after them a feature whose orders
they changed is refitted on the record (with_refitted_orders), a class model's in-context ARX feature starts
from the record's least-squares ARX (with_record_prior), and its windows fit the record's split
(record_horizon). The steps around training are mop.recipe.training's: the source's weights at step 0
(mop.recipe.source) and the correction's gain after the last step (train.shrink_correction,
mop.recipe.shrink); keeping the best validation weights is the loop's option train.keep_best. within_budget
cuts a fine-tune's steps to a budget in minutes at this machine's step time (mop.estimators.Learned's).
Each step that looks at the record is handed it (a RecordedData: the records in memory, split as
config.data asks), never a path to read.
"""

from __future__ import annotations

import dataclasses
import math

from mop.config import (
    RunConfig,
    TrainConfig,
    apply_overrides,
    parse_overrides,
)
from mop.errors import MopError
from mop.experiments.presets import default_preset, preset_config
from mop.models import build_model, reads_features
from mop.recipe.budget import DEFAULT_BUDGET_MINUTES, check_budget
from mop.recipe.given import named_records, run_records, split, with_records
from mop.recipe.records import FEATURE_KEYS as RECIPE_FEATURE_KEYS
from mop.recipe.records import budget_plan, fitted_long_orders, plan_records, record_orders, records_body
from mop.recipe.source import PRIOR_KEYS
from mop.runs import load_config
from mop.train import resolve_config, resolve_device
from mop.train.estimate import step_seconds
from mop.train.records import RecordedData, TrainingRecords

# 125: on the tank_records plants 1-6 (pretrained:cascaded-tanks fine-tuned on est.csv, seeds 0 / 1, the
# validation record simulated from steps 0, 50 and 200; with the record's moments and tails from step 1) the
# 36 simulations average 0.450 V RMSE after 125 steps against 0.476 after 250 (before those two:
# 250 steps 0.616, 500 0.644, 125 0.626 on plants 1, 5, 3); the held-out 10%'s simulation, which picks the
# kept weights, still falls later, but the simulation of a record the fine-tune never saw stops improving
# earlier (README.md at 07be122, "Class models")
FINE_TUNE_STEPS = 125

FINE_TUNE_LR_FACTOR = 0.1


# a source trained for simulation (train.simulate_after > 0) fine-tunes with its simulated tails starting
# anywhere from step 1 of each window: a record is simulated from wherever its user starts, its first step
# included (the benchmarks' protocol), and with the record's moments (RECORD_PRIOR_STEPS) the network acts
# there. tank_records plants 1 / 5 / 3 from steps 0, 50, 200 (seeds 0 / 1): 18 simulations at 0.546 mean
# RMSE against 0.571 with the source's start scaled to the windows (step 41 of 103); 3 Wiener-Hammerstein
# systems: 0.349 against 0.377, all 18 below their fitted ARX against 13 (README.md at 07be122)
FINE_TUNE_SIMULATE_AFTER = 1


def with_fine_tuning(config: RunConfig, source: RunConfig, init: str) -> RunConfig:
    """The fine-tuning layer: train.init, the short schedule (simulated tails from step
    FINE_TUNE_SIMULATE_AFTER where the source was trained for simulation), and the source's fitted
    normalisation (the windows are fitted to the record's split after the overrides: training_config)."""
    train = dataclasses.replace(
        config.train,
        init=str(init),
        steps=FINE_TUNE_STEPS,
        lr=source.train.lr * FINE_TUNE_LR_FACTOR,
        warmup_steps=0,
        lr_schedule="constant",
        keep_best=True,
        simulate_after=FINE_TUNE_SIMULATE_AFTER if source.train.simulate_after else 0,
        context_prefix=0,  # the record is its own estimation record (with_record_prior fits on it)
    )
    data, model = config.data, config.model
    if data is not None and source.data is not None and source.data.fitted:
        kept = {k: getattr(source.data, k) for k in ("y_mean", "y_std", "u_mean", "u_std")}
        data = dataclasses.replace(data, **kept)
    if data is not None:  # the record's normalisation replaces a simulated source's family units
        model = dataclasses.replace(model, output_units=None, input_units=None)
    return dataclasses.replace(config, model=model, train=train, data=data)


# record_norm's pseudo-steps at the estimation record's moments (model.record_prior_steps) in a fine-tune
RECORD_PRIOR_STEPS = 100


def with_record_prior(
    config: RunConfig, record: RecordedData | None, overrides: list[str], source: RunConfig
) -> RunConfig:
    """Fine-tuning a class model (model.record_norm: its ARX feature identifies the record in context) on a
    record with complete outputs: the feature starts from the ARX fitted by least squares on the training
    part (model.rls_prior = "fit", P_0 = 1e-3 I in the run's normalised units), as the records recipe's
    does, so from its first steps the model reads the record's ARX rather than one identified from those
    steps alone, unless an override names the prior (PRIOR_KEYS). The feature's orders are those `mop fit arx
    REC` chooses on the whole record (record_orders), or on a long record a longer ARX(P, P) that simulates
    the training part's held-out end better (the records recipe's fitted_long_orders, P at most half the
    windows), unless an override names model.rls_order or model.arx_order: simulated with the correction's
    gain 0 (mop.recipe.shrink) the model is then the linear model the user fits on REC (refitted on the
    training part; a simulation reads no outputs to update it).
    Measured with scripts/carry_over.py, seeds 0 / 1, simulations from steps 0, 50, 200 (README.md at
    07be122), against the source's ARX(10, 10): tank plants 1-6 below their fitted ARX in 32 of 36 (mean
    RMSE 0.471) against 24 (0.465), Wiener-Hammerstein 1-3 in 18 of 18 both (0.341 against 0.326),
    noise-free LTI 1-3 0.0183 against 0.0239. With the orders chosen on the training part alone (the records
    recipe's fitted_orders) 24 of 36 tank simulations were below (0.506): the order choice moves with the
    steps it reads, and the fitted model the user compares with is fitted on the whole record. And where
    the run normalises the data by the record's own mean and std (a source without recorded data's
    normalisation), record_norm's moments start from RECORD_PRIOR_STEPS pseudo-steps at them
    (model.record_prior_steps) unless an override names it: the plant's scale is known from step 0, so a
    record simulated from its start is not read with an output std of 0, which would leave the first window
    (model.context steps) to the feature alone. The correction's gain is chosen after training by the
    records recipe's held-out check (mop.recipe.selection: free-run simulation of the record's held-out
    tail, gains 0..1 and `mop fit arx`'s ARX), not by simulating the whole record the fine-tune trained on
    (train.shrink_correction, now opt-in): on the first 1024 Silverbox samples, pretrained:duffing
    fine-tuned kept gain 0.5 by its own record (RMSE 0.01024 against 0.01035 at gain 0) and simulated the
    three tests at 2.41 / 11.2 / 2.50 mV; the held-out tail kept gain 0 and 0.65 / 0.70 / 0.53 mV."""
    m, named = config.model, parse_overrides(overrides)
    if record is None or not reads_a_fit(source) or m.rls_order == 0 or m.rls_prior != "none":
        return config
    if any(f"model.{key}" in named for key in PRIOR_KEYS) or record.num_missing:
        return config
    model = dataclasses.replace(m, rls_prior="fit", rls_p0=1.0, rls_prior_cov=None)
    keys = ("model.rls_order", "model.arx_order")
    # a cubic feature (model.rls_cubes) keeps the class's lags: the ARX orders `mop fit arx` chooses are
    # those of a linear model, and may be fewer than the cubed lags
    linear = m.rls_cubes == 0
    if linear and m.arx_order > 0 and record.input_dim and not any(k in named for k in keys):
        orders = record_orders(record)
        if orders is not None:
            longest = config.train.horizon // 2  # the windows stay at least twice the orders
            p, q = fitted_long_orders(record.training_part, *orders, max_order=longest)
            long = (p, q) != orders  # a long ARX stays at its fit (model.rls_fixed), as the records recipe's
            model = dataclasses.replace(model, rls_order=p, arx_order=q, rls_fixed=long)
    own_units = source.data is None or not source.data.fitted
    if m.record_norm == "causal" and own_units and "model.record_prior_steps" not in named:
        model = dataclasses.replace(model, record_prior_steps=RECORD_PRIOR_STEPS)
    return dataclasses.replace(config, model=model)


def records_start(source: RunConfig) -> bool:
    """Whether `source` is a network of the records recipe's shape (no record_norm: it reads a record in
    the record's global units) pretrained on simulated systems, each window read after its estimation
    record's fit (train.context_prefix): a start for the records recipe rather than a model to nudge. Its
    fine-tune is the records recipe from its weights (with_records_recipe)."""
    return source.model.record_norm == "none" and source.train.context_prefix > 0


def with_records_recipe(
    config: RunConfig,
    record: RecordedData,
    overrides: list[str],
    minutes: float = DEFAULT_BUDGET_MINUTES,
) -> RunConfig:
    """A fine-tune of a records start (records_start) on config.data: the records recipe from the source's
    weights. Its schedule: the steps `minutes` buy on the record (mop.recipe.budget, as `mop train --data
    --budget` plans them on windows of the source's length) at the default preset's batch size, learning rate,
    schedule and warm-up, instead of FINE_TUNE_STEPS at a tenth of the source's rate. Its feature, on a record
    with inputs and complete outputs where no override names one: the records recipe's
    (mop.recipe.records.plan_records: the ARX orders, cubed lags or long ARX it picks on the training part,
    started from their least-squares fit; the network reads the feature's prediction whatever its orders),
    else the class model's rule (with_record_prior). On the F-16 (one output, seed 0) the 125-step fine-tune
    of the duffing-class start kept the fitted ARX (held-out 0.3877 at gain 0); the records recipe's 9375
    steps from it the network at gain 0.75 (0.3239; tests 0.1678 / 0.2903 / 0.4232, against 0.2339 / 0.3474 /
    0.4589 from random weights; docs/results/benchmarks.md)."""
    base = preset_config(default_preset()).train
    config = dataclasses.replace(config, train=dataclasses.replace(config.train, batch_size=base.batch_size))
    train = dataclasses.replace(
        config.train,
        steps=budget_plan(record.training_part, config.train.batch_size, config.train.horizon, minutes).steps,
        lr=base.lr,
        lr_schedule=base.lr_schedule,
        warmup_steps=base.warmup_steps,
    )
    config = dataclasses.replace(config, train=train)
    named = parse_overrides(overrides)
    if not record.input_dim or record.num_missing or any(k in named for k in RECIPE_FEATURE_KEYS):
        return config
    plan = plan_records(record.training_part, config, minutes)
    model = dataclasses.replace(
        config.model,
        rls_order=plan.p,
        arx_order=plan.q,
        rls_cubes=plan.cubes,
        rls_offset=True,
        rls_prior="fit",
        rls_p0=1.0,
        rls_prior_cov=None,
        rls_fixed=plan.fixed,
    )
    horizon = plan.horizon if plan.longer else train.horizon
    if horizon > model.context:  # the source's windows are its context: the feature regresses on less
        horizon = train.horizon
    train = dataclasses.replace(train, steps=plan.steps, horizon=horizon)
    return dataclasses.replace(config, model=model, train=train)


def with_records_body(config: RunConfig, record: RecordedData, minutes: float) -> RunConfig:
    """A fine-tune of a records start without a feature (the records recipe's own network, RECORDS_BODY:
    pretrained:cascaded-tanks-lru) on config.data: the records recipe of that network from the source's
    weights, as `mop train --data` trains it from random weights (mop.recipe.records.records_body: its
    batch, its windows on the record, its simulated tails from step 5 on, the default preset's learning
    rate and schedule), for the steps `minutes` buy on the record."""
    base = preset_config(default_preset()).train
    body = records_body(record)
    horizon = min(body["train.horizon"], config.model.context)  # the source's context is its weights'
    train = dataclasses.replace(
        config.train,
        batch_size=body["train.batch_size"],
        horizon=horizon,
        simulate_after=min(body["train.simulate_after"], horizon - 1),
        lr=base.lr,
        lr_schedule=base.lr_schedule,
        warmup_steps=base.warmup_steps,
    )
    steps = budget_plan(record.training_part, train.batch_size, horizon, minutes).steps
    return dataclasses.replace(config, train=dataclasses.replace(train, steps=steps))


def reads_a_fit(source: RunConfig) -> bool:
    """Whether `source` reads a feature that can start from a record's least-squares fit: a class model
    (model.record_norm = "causal", its ARX feature identified in context), or a model trained on simulated
    systems with an estimation record before each window (train.context_prefix: its feature was each
    record's fit, as the records recipe's is the record's)."""
    return source.model.record_norm == "causal" or source.train.context_prefix > 0


def with_refitted_orders(config: RunConfig, source: RunConfig) -> RunConfig:
    """A fine-tune whose override changed the feature's orders (mop.recipe.source.ORDER_KEYS) refits the
    feature's start on the record (model.rls_prior = "fit") where the source's start is a list of
    coefficients: those are of the source's orders."""
    m, s = config.model, source.model
    if (m.rls_order, m.arx_order, m.rls_offset, m.rls_cubes) == (
        s.rls_order,
        s.arx_order,
        s.rls_offset,
        s.rls_cubes,
    ):
        return config
    if not isinstance(m.rls_prior, list) or config.data is None:
        return config
    refit = dict(rls_prior="fit", rls_prior_cov=None, rls_prior_weights=None, rls_prior_noise=0.0)
    return dataclasses.replace(config, model=dataclasses.replace(m, **refit))


def record_horizon(train: TrainConfig, record: RecordedData, validation_fraction: float) -> TrainConfig:
    """A source trained on longer windows than the record's split holds trains on the longest that fit
    both sides (train.simulate_after scaled alike), so `--init` works on a short record as it is. With a
    validation record (--val) the windows are those the split in time would give, as long as the last
    data.validation_fraction of the estimation record: the same fine-tune with or without --val (windows
    of 500 steps on one record of 1024 fit its tail and simulate the validation record worse, measured)."""
    longest = [max(len(a) for a in record.train_parts), max(len(a) for a in record.val_parts)]
    if record.split == "file":
        longest.append(max(math.ceil(validation_fraction * len(a)) for a in record.train_parts))
    fits = min(longest) - 1
    if not 2 <= fits < train.horizon:
        return train
    after = (
        min(max(round(train.simulate_after * fits / train.horizon), 1), fits) if train.simulate_after else 0
    )
    return dataclasses.replace(train, horizon=fits, simulate_after=after)


def within_budget(config: RunConfig, minutes: float, records: TrainingRecords | None = None) -> RunConfig:
    """config with train.steps cut to what `minutes` allow at the measured time of one step (on this machine:
    mop.train.estimate.step_seconds), never raised."""
    resolved = resolve_config(config, records)
    device = resolve_device(resolved.train.device)
    seconds = step_seconds(resolved, build_model(resolved.model), device)
    steps = max(1, min(config.train.steps, int(minutes * 60 / max(seconds, 1e-9))))
    return dataclasses.replace(config, train=dataclasses.replace(config.train, steps=steps))


def fine_tune_config(
    source: str | None,
    preset: str | None,
    records: TrainingRecords | None,
    overrides: list[str],
    init: str,
    budget: float | None,
) -> tuple[RunConfig, TrainingRecords | None]:
    """(config, the records it trains on) of `mop train --data FILE --init SOURCE [key=value ...]`: the
    source's RunConfig with the records named (mop.recipe.given), the fine-tuning layer (with_fine_tuning;
    a records start's records recipe, with_records_recipe, or with_records_body for one without a
    feature), the overrides, then the steps that fit the feature and the windows to the record's split (see
    mop.recipe.layers' docstring)."""
    if budget is not None:
        check_budget(budget)
    if budget is not None and records is None:
        raise MopError("--budget MINUTES plans training on a record: give --data FILE too (or train.steps=N)")
    if budget is not None and not records_start(load_config(init)):
        raise MopError(
            "--budget plans the records recipe; a fine-tune (--init) has its own schedule: drop it"
        )
    if source is not None or preset is not None:
        given = source if source is not None else f"--preset {preset}"
        raise MopError(f"--init {init} fixes the model and its recipe: drop {given} (override keys instead)")
    base = load_config(init)
    records = run_records(records, base)
    config = with_fine_tuning(with_records(base, records), base, init)
    body_start = records_start(base) and not reads_features(base.model.arch)  # the records recipe's deep LRU
    if records_start(base) and config.data is not None:
        minutes = DEFAULT_BUDGET_MINUTES if budget is None else budget
        estimation = split(config, records)
        if body_start:  # its windows are the records recipe's: record_horizon below leaves them
            config = with_records_body(config, estimation, minutes)
        else:
            config = with_records_recipe(config, estimation, list(overrides), minutes)
    config = with_refitted_orders(apply_overrides(config, list(overrides)), base)
    records = named_records(records, config)
    record = split(config, records)  # the split the overrides ask for (data.validation_fraction, data.split)
    config = with_record_prior(config, record, list(overrides), base)
    if record is not None and not body_start and "train.horizon" not in parse_overrides(list(overrides)):
        # the windows fit that split
        fraction = config.data.validation_fraction
        config = dataclasses.replace(config, train=record_horizon(config.train, record, fraction))
    return config, records
