"""The RunConfig that `mop train` trains, from what the user gave.

Layers, later wins:
1. the base: a preset on its own (`--preset P`, else default_preset(): "small" on a CPU, "paper" with a GPU),
   an experiment's training under the preset (an experiment name or a .toml / .json experiment file, as
   `mop reproduce` reads them), or a RunConfig .json file (its sizes are its own: no --preset);
2. `--data FILE` (data.path) and `--val FILE` (data.validation_path): recorded trajectories;
3. on recorded data with inputs and complete outputs, where no source, no --preset and no override chose
   the feature, the
   records recipe (recorded_recipe): a 1 x 32 model for the steps its budget buys on the record
   (mop.train.budget: --budget MINUTES, default 5) whose ARX(p, q) feature with an
   intercept starts from the least-squares ARX of the training part (model.rls_prior = "fit"), the orders
   those `mop fit arx` chooses on that part (held-out free-run simulation); the last weights are kept (not
   train.keep_best: its one-step validation loss on one record's last 10% picked step 500 of seed 1 on
   tank_records --plant 5, which simulates at 1.009 against 0.49 at step 1000);
4. the dotted key=value overrides.
With `--init SOURCE` (a run directory or pretrained:NAME; fine-tuning, mop.train.init) the base is the
source's own RunConfig (its model, so the architecture is the source's; its data normalisation kept, where
it was trained on recorded data), layer 3 is skipped, and FINE_TUNE sets a short schedule before the
overrides: FINE_TUNE_STEPS steps at a tenth of the source's learning rate, constant, no warm-up (the weights
are trained already: a warm-up from zero and the source's full rate would first move them away from what
they learned; 125 steps of batch 16 on a 2-core CPU take seconds to a minute), keeping the weights of the
lowest validation loss, the source's at step 0 included (train.keep_best: never worse than the source there).
After the overrides, a feature whose orders they changed is refitted on the record (with_refitted_orders), a
class model's in-context ARX feature starts from the record's least-squares ARX (with_record_prior), and its
windows fit the record's split (_record_horizon).
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np

from mop.config import (
    DataConfig,
    RunConfig,
    TrainConfig,
    apply_overrides,
    apply_settings,
    from_dict,
    parse_overrides,
)
from mop.errors import MopError
from mop.experiments import get_experiment, run_config
from mop.experiments.files import is_experiment_file, load_experiment
from mop.experiments.presets import default_preset, preset_config
from mop.identify.arx import ARX
from mop.identify.cubic import choose_cubes
from mop.identify.select import feasible_order, fit
from mop.io import Data as RecordData
from mop.io import read_trajectories
from mop.runs import load_config
from mop.train.auto import FEATURE_KEYS as AUTO_KEYS
from mop.train.auto import resolve_features
from mop.train.budget import DEFAULT_BUDGET_MINUTES, BudgetPlan, check_budget, plan_steps
from mop.train.init import PRIOR_KEYS
from mop.train.records import recorded_data, window_count

# The records recipe (docs/results/families.md: measured on examples/tank_records.py, one record of 1024
# samples): a small network reading the fitted ARX's prediction and predicting its residual, so it starts as
# that ARX; the 2 x 64 small-preset model trained 2500 steps overfits one record (one-step RMSE 2.5x ARX's)
RECORDED_MODEL = {"model.num_layers": 1, "model.width": 32, "model.num_heads": 2}
# the identifier's keys (mop.train.auto's feature keys but the running scale): naming one turns the recipe off
FEATURE_KEYS = tuple(f"model.{key}" for key in AUTO_KEYS if key != "input_scale")


def base_config(source: str | None, preset: str | None) -> RunConfig:
    """Layer 1: a preset, an experiment's training under a preset, or a RunConfig JSON file."""
    if source is None:
        return preset_config(preset or default_preset())
    path = Path(source)
    if not (is_experiment_file(source) or path.exists()):
        return _named_experiment(source, preset)
    if not path.is_file():
        raise MopError(f"config file {path} does not exist")
    if path.suffix == ".toml":
        return run_config(load_experiment(path), preset or default_preset())
    data = _read_json(path)
    if isinstance(data, dict) and "conditions" in data:  # an experiment file in JSON
        return run_config(load_experiment(path), preset or default_preset())
    if preset:
        raise MopError(f"{path} is a RunConfig: it fixes the model and training; drop --preset {preset}")
    return from_dict(RunConfig, data)


def _read_json(path: Path) -> object:
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise MopError(f"{path} is not valid JSON ({err.msg} at line {err.lineno})") from None
    except UnicodeDecodeError:
        raise MopError(f"{path} is not valid JSON (not text)") from None


def _named_experiment(name: str, preset: str | None) -> RunConfig:
    try:
        exp = get_experiment(name)
    except (ImportError, AttributeError):
        raise MopError(
            f"{name!r} is neither a config file (.json, .toml) nor a known experiment (mop reproduce --help)"
        ) from None
    return run_config(exp, preset or default_preset())


def with_records(config: RunConfig, data: str | None, val: str | None) -> RunConfig:
    """Layer 2: --data and --val; the normalisation is left to the trainer (a saved config's is refitted)."""
    if data is None:
        if val is not None:
            raise MopError("--val FILE is the validation record of --data FILE: give --data too")
        return config
    unfitted = dict.fromkeys(("y_mean", "y_std", "u_mean", "u_std"))
    base = config.data or DataConfig(path=data)
    return dataclasses.replace(
        config,
        data=dataclasses.replace(base, path=data, validation_path=val or base.validation_path, **unfitted),
    )


def arx_orders(data: RecordData, source: str) -> tuple[int, int] | None:
    """(p, q): the ARX orders `mop fit arx` chooses on `data` (mop.identify.select.fit: free-run
    simulation of its last 20%); on data too short for orders up to 10, those of `--max-order P` with the
    largest P it allows; None where it allows none."""
    largest = feasible_order(ARX.kind, data, source=source)
    if largest == 0:
        return None
    orders = fit(ARX.kind, data, max_order=largest, source=source).orders
    return orders["p"], orders["q"]


def fitted_orders(data: DataConfig) -> tuple[int, int]:
    """(p, q): arx_orders on the record's training part (the records recipe's feature)."""
    record = recorded_data(data)
    m = record.output_dim
    orders = arx_orders([(a[:, :m], a[:, m:]) for a in record.train_parts], data.path)
    if orders is None:
        raise MopError(
            f"{data.path}: its training part is too short to fit the records recipe's ARX feature; give a "
            "longer record, or name the model's feature (model.rls_order=0 for none)"
        )
    return orders


def fitted_cubes(data: DataConfig, p: int, q: int) -> tuple[int, int]:
    """(p, c): the output lags and cubed lags of the records recipe's feature, by held-out free-run
    simulation of cubic NARX candidates on the record's training part (mop.identify.cubic.choose_cubes,
    normalised as the network reads it); (p, 0) keeps the ARX(p, q) `mop fit arx` chose."""
    record = recorded_data(data)
    if record.num_missing:
        return p, 0
    stats = record.fit()
    mean = np.array([*stats["y_mean"], *stats["u_mean"]])
    std = np.array([*stats["y_std"], *stats["u_std"]])
    m = record.output_dim
    parts = [((a - mean) / std) for a in record.train_parts]
    p, c, _ = choose_cubes([(a[:, :m], a[:, m:]) for a in parts], p, q)
    return p, c


def record_orders(path: str) -> tuple[int, int] | None:
    """(p, q): arx_orders on the whole estimation record at `path`, its validation part included: the
    orders of `mop fit arx PATH`."""
    return arx_orders(read_trajectories(path)[1], path)


def budget_plan(config: RunConfig, minutes: float = DEFAULT_BUDGET_MINUTES) -> BudgetPlan:
    """The steps `minutes` buy on config.data's training windows (mop.train.budget.plan_steps)."""
    record = recorded_data(config.data)
    windows = window_count(record.train_parts, config.train.horizon)
    return plan_steps(minutes, windows, config.train.batch_size)


def recorded_recipe(
    config: RunConfig, budget: float = DEFAULT_BUDGET_MINUTES, cubes: bool = True
) -> dict[str, object]:
    """The records recipe's settings for config.data: the ARX orders `mop fit arx` chooses on the training
    part (fitted_orders), cubed output lags where a cubic NARX simulates the held-out end of the training
    part better (fitted_cubes), the feature started from their least-squares fit, RECORDED_MODEL, and the
    steps the budget (minutes) buys on the record (budget_plan: longer records train longer)."""
    p, q = fitted_orders(config.data)
    p, c = fitted_cubes(config.data, p, q) if cubes else (p, 0)
    return {
        **RECORDED_MODEL,
        "train.steps": budget_plan(config, budget).steps,
        "model.rls_order": p,
        "model.arx_order": q,
        "model.rls_cubes": c,
        "model.rls_offset": True,
        "model.rls_prior": "fit",
    }


def given_features(config: RunConfig, overrides: list[str]) -> RunConfig:
    """config with model.features="given" where an override names a feature key (model.rls_order, ...)
    and none names model.features: the named keys, not the preset's auto, set the features."""
    named = parse_overrides(overrides)
    if "model.features" in named or not any(k.startswith("model.") and k[6:] in AUTO_KEYS for k in named):
        return config
    return dataclasses.replace(config, model=dataclasses.replace(config.model, features="given"))


def with_recorded_features(
    config: RunConfig, overrides: list[str], chosen: bool = False, budget: float = DEFAULT_BUDGET_MINUTES
) -> RunConfig:
    """Layer 3: the records recipe on recorded data with inputs and complete outputs, unless the source or
    --preset (`chosen`), the base's feature or an override chose the feature (overrides of sizes and steps
    apply on top of it, as layer 4)."""
    named = parse_overrides(overrides)
    if config.data is None or chosen or config.model.rls_order > 0:
        return config
    if any(k in named for k in FEATURE_KEYS):
        return config
    data = recorded_data(config.data)
    if data.input_dim == 0 or data.num_missing:
        return config
    return apply_settings(config, recorded_recipe(config, budget, cubes="model.rls_cubes" not in named))


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


def with_record_prior(config: RunConfig, overrides: list[str], source: RunConfig) -> RunConfig:
    """Fine-tuning a class model (model.record_norm: its ARX feature identifies the record in context) on a
    record with complete outputs: the feature starts from the ARX fitted by least squares on the training
    part (model.rls_prior = "fit", P_0 = 1e-3 I in the run's normalised units), as the records recipe's
    does, so from its first steps the model reads the record's ARX rather than one identified from those
    steps alone, unless an override names the prior (PRIOR_KEYS). The feature's orders are those `mop fit arx
    REC` chooses on the whole record (record_orders), unless an override names model.rls_order or
    model.arx_order: simulated with the correction's gain 0 (mop.train.shrink) the model is then the linear
    model the user fits on REC (refitted on the training part; a simulation reads no outputs to update it).
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
    (model.context steps) to the feature alone. A source trained for simulation (train.simulate_after) with
    the mean read-out also scales its correction by the gain that simulates the record best
    (train.shrink_correction, mop.train.shrink), unless an override names it."""
    m, named = config.model, parse_overrides(overrides)
    if config.data is None or m.record_norm == "none" or m.rls_order == 0 or m.rls_prior != "none":
        return config
    if any(f"model.{key}" in named for key in PRIOR_KEYS) or recorded_data(config.data).num_missing:
        return config
    model = dataclasses.replace(m, rls_prior="fit", rls_p0=1.0, rls_prior_cov=None)
    keys = ("model.rls_order", "model.arx_order")
    if m.arx_order > 0 and recorded_data(config.data).input_dim and not any(k in named for k in keys):
        orders = record_orders(config.data.path)
        if orders is not None:
            model = dataclasses.replace(model, rls_order=orders[0], arx_order=orders[1])
    own_units = source.data is None or not source.data.fitted
    if own_units and "model.record_prior_steps" not in named:
        model = dataclasses.replace(model, record_prior_steps=RECORD_PRIOR_STEPS)
    train = config.train
    if source.train.simulate_after and m.readout == "mean" and "train.shrink_correction" not in named:
        train = dataclasses.replace(train, shrink_correction=True)
    return dataclasses.replace(config, model=model, train=train)


def with_refitted_orders(config: RunConfig, source: RunConfig) -> RunConfig:
    """A fine-tune whose override changed the feature's orders (mop.train.init.ORDER_KEYS) refits the
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


def _record_horizon(train: TrainConfig, data: DataConfig) -> TrainConfig:
    """A source trained on longer windows than the record's split holds trains on the longest that fit
    both sides (train.simulate_after scaled alike), so `--init` works on a short record as it is. With a
    validation record (--val) the windows are those the split in time would give, as long as the last
    data.validation_fraction of the estimation record: the same fine-tune with or without --val (windows
    of 500 steps on one record of 1024 fit its tail and simulate the validation record worse, measured)."""
    split = recorded_data(data)
    longest = [max(len(a) for a in split.train_parts), max(len(a) for a in split.val_parts)]
    if split.split == "file":
        longest.append(max(math.ceil(data.validation_fraction * len(a)) for a in split.train_parts))
    fits = min(longest) - 1
    if not 2 <= fits < train.horizon:
        return train
    after = (
        min(max(round(train.simulate_after * fits / train.horizon), 1), fits) if train.simulate_after else 0
    )
    return dataclasses.replace(train, horizon=fits, simulate_after=after)


def training_config(
    source: str | None,
    preset: str | None = None,
    data: str | None = None,
    val: str | None = None,
    overrides: list[str] = (),
    init: str | None = None,
    budget: float | None = None,
) -> RunConfig:
    """The RunConfig of `mop train [SOURCE] [--preset P] [--data FILE [--val FILE]] [--init RUN]
    [--budget MINUTES] [key=value ...]`; the budget (DEFAULT_BUDGET_MINUTES where None) plans the records
    recipe's steps."""
    if budget is not None:
        check_budget(budget)
    if budget is not None and data is None:
        raise MopError("--budget MINUTES plans training on a record: give --data FILE too (or train.steps=N)")
    if budget is not None and init is not None:
        raise MopError(
            "--budget plans the records recipe; a fine-tune (--init) has its own schedule: drop it"
        )
    if init is None:
        config = with_records(base_config(source, preset), data, val)
        chosen = source is not None or preset is not None
        minutes = DEFAULT_BUDGET_MINUTES if budget is None else budget
        config = with_recorded_features(config, list(overrides), chosen, minutes)
        config = apply_overrides(given_features(config, list(overrides)), list(overrides))
        return resolve_features(config, scale_steps="train.steps" not in parse_overrides(list(overrides)))
    if source is not None or preset is not None:
        given = source if source is not None else f"--preset {preset}"
        raise MopError(f"--init {init} fixes the model and its recipe: drop {given} (override keys instead)")
    base = load_config(init)
    config = with_fine_tuning(with_records(base, data, val), base, init)
    config = with_refitted_orders(apply_overrides(config, list(overrides)), base)
    config = with_record_prior(config, list(overrides), base)
    if config.data is not None and "train.horizon" not in parse_overrides(list(overrides)):
        # the windows fit the split the overrides ask for (data.validation_fraction, data.split)
        config = dataclasses.replace(config, train=_record_horizon(config.train, config.data))
    return config


def feature_line(config: RunConfig) -> str | None:
    """One line naming the input feature a records run reads, or None without one."""
    m = config.model
    if m.rls_order == 0:
        return None
    kind = f"ARX({m.rls_order}, {m.arx_order})" if m.arx_order else f"RLS-AR({m.rls_order})"
    if m.rls_cubes:
        kind = f"cubic NARX ({kind} with the cubes of its first {m.rls_cubes} output lags)"
    start = " started from its least-squares fit on the training part" if m.rls_prior != "none" else ""
    offset = " with an intercept" if m.rls_offset else ""
    return (
        f"feature: the network reads the {kind}{offset} one-step prediction{start}, and predicts its residual"
    )


def order_line(
    config: RunConfig, overrides: list[str], init: str | None = None, chosen: bool = False
) -> str | None:
    """One line saying which rule chose the ARX feature's orders of a run on recorded data (None without an
    ARX feature): `mop fit arx` scores the orders on the whole record, the records recipe on its training
    part only (its held-out part must stay unseen), a fine-tune on the whole record; so the three can
    differ on the same record. chosen: the source or --preset chose the config (no records recipe)."""
    m = config.model
    if config.data is None or m.rls_order == 0 or m.arx_order == 0:
        return None
    orders = f"ARX({m.rls_order}, {m.arx_order})"
    if any(k in parse_overrides(list(overrides)) for k in ("model.rls_order", "model.arx_order")):
        return f"orders: {orders}, as the key=value overrides name them"
    rule = "the orders `mop fit arx` chooses (free-run simulation of the last 20% of each trajectory)"
    if init is not None:
        if m.rls_prior == "fit":
            return f"orders: {orders}, {rule} on the whole record, as `mop fit arx {config.data.path}` does"
        return f"orders: {orders}, the source model's (--init {init})"
    if not chosen and m.rls_prior == "fit":
        line = (
            f"orders: {orders}, {rule} on the training part only (the held-out part stays unseen), so they "
            f"can differ from `mop fit arx` on the whole record"
        )
        if m.rls_cubes:
            line += (
                f"; then {m.rls_order} output lags, {m.rls_cubes} of them cubed: the cubic NARX that "
                "simulates the last 20% of the training part best "
                "and stays bounded when driven twice as hard "
                "(mop.identify.cubic)"
            )
        return line
    return f"orders: {orders}, as the config sets them"
