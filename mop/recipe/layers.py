"""The RunConfig that `mop train` trains, from what the user gave.

Layers, later wins:
1. the base: a preset on its own (`--preset P`, else default_preset(): "small" on a CPU, "paper" with a GPU),
   an experiment's training under the preset (an experiment name or a .toml / .json experiment file, as
   `mop reproduce` reads them), or a RunConfig .json file (its sizes are its own: no --preset);
2. `--data FILE` (data.path) and `--val FILE` (data.validation_path): recorded trajectories;
3. on recorded data with inputs and complete outputs, where no source, no --preset and no override chose
   the feature, the records recipe (plan_records, a RecordsPlan; mop.recipe.plan): its network for the steps
   its budget buys on the record (mop.recipe.budget: --budget MINUTES, default 5): where no model.arch is
   named, the deep LRU trained on its free-run simulation error (RECORDS_BODY), with the least-squares
   feature the recipe chooses on the training part (ARX, cubic NARX or longer ARX) left to the held-out check
   as a model of its own; with model.arch=gpt a 1 x 32 transformer reading that feature's one-step prediction
   (an ARX(p, q) with an intercept started from its least-squares fit, model.rls_prior = "fit", the orders
   `mop fit arx` chooses on that part) and predicting its residual; the last weights are kept (not
   train.keep_best: its one-step validation loss on one record's last 10% picked step 500 of seed 1 on
   tank_records --plant 5, which simulates at 1.009 against 0.49 at step 1000);
4. the dotted key=value overrides.
A run from scratch takes them in one downward sequence (scratch_config): the records named (mop.recipe.given),
split once, the plan made on the split's training part, the overrides, the features resolved.
With `--init SOURCE` (a run directory or pretrained:NAME; fine-tuning, mop.recipe.source; its own sequence,
mop.recipe.finetune.fine_tune_config) the base is the
source's own RunConfig (its model, so the architecture is the source's; its data normalisation kept, where
it was trained on recorded data), layer 3 is skipped, and FINE_TUNE sets a short schedule before the
overrides: FINE_TUNE_STEPS steps at a tenth of the source's learning rate, constant, no warm-up (the weights
are trained already: a warm-up from zero and the source's full rate would first move them away from what
they learned; 125 steps of batch 16 on a 2-core CPU take seconds to a minute), keeping the weights of the
lowest validation loss, the source's at step 0 included (train.keep_best: never worse than the source there).
After the overrides, a feature whose orders they changed is refitted on the record (with_refitted_orders), a
class model's in-context ARX feature starts from the record's least-squares ARX (with_record_prior), and its
windows fit the record's split (record_horizon).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from mop.config import (
    RunConfig,
    apply_overrides,
    from_dict,
    parse_overrides,
)
from mop.errors import MopError
from mop.experiments import get_experiment, run_config
from mop.experiments.files import is_experiment_file, load_experiment
from mop.experiments.presets import default_preset, preset_config
from mop.recipe.budget import DEFAULT_BUDGET_MINUTES, check_budget
from mop.recipe.finetune import fine_tune_config
from mop.recipe.given import named_records, read_given, run_records, split, with_records
from mop.recipe.records import gaps_turn_off_recipe, with_recorded_features
from mop.train.auto import FEATURE_KEYS as AUTO_KEYS
from mop.train.auto import resolve_features
from mop.train.records import RecordedData, TrainingRecords


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


def given_features(config: RunConfig, overrides: list[str]) -> RunConfig:
    """config with model.features="given" where an override names a feature key (model.rls_order, ...)
    and none names model.features: the named keys, not the preset's auto, set the features."""
    named = parse_overrides(overrides)
    if "model.features" in named or not any(k.startswith("model.") and k[6:] in AUTO_KEYS for k in named):
        return config
    return dataclasses.replace(config, model=dataclasses.replace(config.model, features="given"))


def training_config(
    source: str | None,
    preset: str | None = None,
    data: str | TrainingRecords | None = None,
    val: str | None = None,
    overrides: list[str] = (),
    init: str | None = None,
    budget: float | None = None,
) -> RunConfig:
    """The RunConfig of `mop train [SOURCE] [--preset P] [--data FILE [--val FILE]] [--init RUN]
    [--budget MINUTES] [key=value ...]`; the budget (DEFAULT_BUDGET_MINUTES where None) plans the records
    recipe's steps. data: a file (read here, once, with val's) or the records in memory (TrainingRecords;
    val then None)."""
    if budget is not None:  # before the file is read
        check_budget(budget)
    return records_config(source, preset, read_given(data, val), overrides, init, budget)[0]


def records_config(
    source: str | None,
    preset: str | None = None,
    records: TrainingRecords | None = None,
    overrides: list[str] = (),
    init: str | None = None,
    budget: float | None = None,
) -> tuple[RunConfig, TrainingRecords | None]:
    """(config, the records it trains on): training_config on the records in memory (`records`; None: no
    --data): scratch_config, or with --init the fine-tune's (mop.recipe.finetune.fine_tune_config). No file
    is read here but a config's own (run_records: a RunConfig file or --init source naming its data)."""
    if init is not None:
        return fine_tune_config(source, preset, records, overrides, init, budget)
    return scratch_config(source, preset, records, overrides, budget)[:2]


def scratch_config(
    source: str | None,
    preset: str | None,
    records: TrainingRecords | None,
    overrides: list[str],
    budget: float | None,
) -> tuple[RunConfig, TrainingRecords | None, RecordedData | None]:
    """(config, the records it trains on, their split as it trains on them; None without data) of a run
    from scratch, in one downward sequence: the base (layer 1), the records named (layer 2), the records
    recipe's plan on the record split once (layer 3), the overrides (layer 4), the features resolved."""
    if budget is not None:
        check_budget(budget)
    if budget is not None and records is None:
        raise MopError("--budget MINUTES plans training on a record: give --data FILE too (or train.steps=N)")
    base = base_config(source, preset)
    records = run_records(records, base)
    config = with_records(base, records)
    chosen = source is not None or preset is not None
    gaps = gaps_turn_off_recipe(records, list(overrides), chosen, None) if budget is not None else 0
    if gaps:
        raise MopError(
            f"--budget plans the records recipe, which {records.source} cannot use: it has {gaps} "
            "missing output(s), and the recipe's least-squares feature needs complete outputs; fill the "
            "gaps, or drop --budget and set train.steps=N"
        )
    minutes = DEFAULT_BUDGET_MINUTES if budget is None else budget
    config = with_recorded_features(config, split(config, records), list(overrides), chosen, minutes)
    config = apply_overrides(given_features(config, list(overrides)), list(overrides))
    steps = "train.steps" not in parse_overrides(list(overrides))
    records = named_records(records, config)
    config = resolve_features(config, scale_steps=steps)
    return config, records, split(config, records)
