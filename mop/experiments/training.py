"""The RunConfig that `mop train` trains, from what the user gave.

Layers, later wins:
1. the base: a preset on its own (`--preset P`, else default_preset(): "small" on a CPU, "paper" with a GPU),
   an experiment's training under the preset (an experiment name or a .toml / .json experiment file, as
   `mop reproduce` reads them), or a RunConfig .json file (its sizes are its own: no --preset);
2. `--data FILE` (data.path) and `--val FILE` (data.validation_path): recorded trajectories;
3. on recorded data with inputs, RECORDED_FEATURES, where the base reads no feature and no override names one;
4. the dotted key=value overrides.
With `--init SOURCE` (a run directory or pretrained:NAME; fine-tuning, mop.train.init) the base is the
source's own RunConfig (its model, so the architecture is the source's; its data normalisation kept, where
it was trained on recorded data), layer 3 is skipped, and FINE_TUNE sets a short schedule before the
overrides: FINE_TUNE_STEPS steps at a tenth of the source's learning rate, constant, no warm-up (the weights
are trained already: a warm-up from zero and the source's full rate would first move them away from what
they learned; 500 steps of batch 16 on a 2-core CPU are minutes).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from mop.config import DataConfig, RunConfig, apply_overrides, from_dict, parse_overrides
from mop.errors import MopError
from mop.experiments import get_experiment, run_config
from mop.experiments.files import is_experiment_file, load_experiment
from mop.experiments.presets import default_preset, preset_config
from mop.runs import load_config
from mop.train.records import recorded_data

# The network reads the online ARX(2, 2) one-step prediction with an intercept (mop.models.features) and
# predicts its residual: on records with inputs it starts as ARX rather than from zero. Measured on the
# cascaded-tanks worked example (README, "Recorded data").
RECORDED_FEATURES = {"model.rls_order": 2, "model.arx_order": 2, "model.rls_offset": True}
FEATURE_KEYS = ("model.rls_order", "model.arx_order", "model.rls_offset")


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


def with_recorded_features(config: RunConfig, overrides: list[str]) -> RunConfig:
    """Layer 3: RECORDED_FEATURES on recorded data with inputs, where nothing chose a feature."""
    named = parse_overrides(overrides)
    if config.data is None or config.model.rls_order > 0 or any(k in named for k in FEATURE_KEYS):
        return config
    if recorded_data(config.data).input_dim == 0:
        return config
    return apply_overrides(config, [f"{k}={json.dumps(v)}" for k, v in RECORDED_FEATURES.items()])


FINE_TUNE_STEPS = 500
FINE_TUNE_LR_FACTOR = 0.1


def with_fine_tuning(config: RunConfig, source: RunConfig, init: str) -> RunConfig:
    """The fine-tuning layer: train.init, the short schedule, and the source's fitted normalisation."""
    train = dataclasses.replace(
        config.train,
        init=str(init),
        steps=FINE_TUNE_STEPS,
        lr=source.train.lr * FINE_TUNE_LR_FACTOR,
        warmup_steps=0,
        lr_schedule="constant",
    )
    data = config.data
    if data is not None and source.data is not None and source.data.fitted:
        kept = {k: getattr(source.data, k) for k in ("y_mean", "y_std", "u_mean", "u_std")}
        data = dataclasses.replace(data, **kept)
    return dataclasses.replace(config, train=train, data=data)


def training_config(
    source: str | None,
    preset: str | None = None,
    data: str | None = None,
    val: str | None = None,
    overrides: list[str] = (),
    init: str | None = None,
) -> RunConfig:
    """The RunConfig of `mop train [SOURCE] [--preset P] [--data FILE [--val FILE]] [--init RUN]
    [key=value ...]`."""
    if init is None:
        config = with_records(base_config(source, preset), data, val)
        config = with_recorded_features(config, list(overrides))
        return apply_overrides(config, list(overrides))
    if source is not None or preset is not None:
        given = source if source is not None else f"--preset {preset}"
        raise MopError(f"--init {init} fixes the model and its recipe: drop {given} (override keys instead)")
    base = load_config(init)
    config = with_fine_tuning(with_records(base, data, val), base, init)
    return apply_overrides(config, list(overrides))
