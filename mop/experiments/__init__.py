"""Experiments: the paper's figures (and what goes beyond them) as data, plus the presets that size them.

    exp = get_experiment("linear")                  # or load_experiment("my_experiment.toml")
    config = run_config(exp, "small", seed=0)       # the RunConfig that trains its MOP
    settings = get_preset("small")                  # num_test_systems, ...

A new experiment is one registered Experiment (EXPERIMENTS.add) or one TOML/JSON file; `mop reproduce`
runs either through the one generic runner (mop.experiments.runner).
"""

from __future__ import annotations

import dataclasses

from mop.config import DataConfig, RunConfig, apply_settings, parse_overrides
from mop.experiments.classes import CLASS_EXPERIMENTS
from mop.experiments.inputs import LINEAR_INPUTS
from mop.experiments.missing_data import MISSING_DATA
from mop.experiments.paper import PAPER_EXPERIMENTS
from mop.experiments.presets import PRESETS, Preset, get_preset
from mop.experiments.spec import Claim, Condition, Experiment, Measure
from mop.registry import Registry
from mop.train.auto import FEATURE_KEYS, resolve_features

TEST_SEED_OFFSET = 7_000_001  # test systems: generator seed + this, apart from training (seed) and validation


EXPERIMENTS: Registry = Registry("experiment", group="mop.experiments")
for _exp in (
    *PAPER_EXPERIMENTS,
    MISSING_DATA,
    LINEAR_INPUTS,
    *CLASS_EXPERIMENTS,
):  # the built-in ones (plugins: entry points of mop.experiments)
    EXPERIMENTS.add(_exp.name, _exp)


def get_experiment(name: str) -> Experiment:
    return EXPERIMENTS.get(name)


def run_config(
    exp: Experiment,
    preset: str,
    seed: int = 0,
    arch: str = "gpt",
    condition: Condition | None = None,
    overrides: list[str] = (),
) -> RunConfig:
    """The RunConfig that trains `exp`'s model (architecture `arch`) for `condition` under `preset`.

    A "data.path" key trains on that file of recorded trajectories instead of simulating the family.
    Layers, later wins: the preset's model and train settings < the experiment's `train` < its per-preset
    overrides < the condition's `train` < `overrides` (key=value strings from the command line).
    The model's context is the training horizon unless a layer sets it. model.features=auto (the small
    preset's) is resolved here (mop.train.auto), so the RunConfig, its hash and its saved config hold the
    chosen keys; a layer that names a feature key (model.rls_order, ...) without model.features sets them
    itself (features "given", _features_setting).
    """
    p = get_preset(preset)
    base = RunConfig(
        model=dataclasses.replace(p.model, arch=arch), train=dataclasses.replace(p.train, seed=seed)
    )
    layers = {**exp.train, **exp.presets.get(preset, {}), **(condition.train if condition else {})}
    if "data.path" in layers:  # trained on recorded trajectories (mop train --data)
        base = dataclasses.replace(base, data=DataConfig(path=layers["data.path"]))
    given = parse_overrides(list(overrides))
    settings = {**layers, **given}
    features = _features_setting(
        (exp.train, exp.presets.get(preset, {}), condition.train if condition else {}, given)
    )
    if features:
        settings["model.features"] = features
    config = apply_settings(base, settings)  # one merge of the layers' dicts, no key=value strings
    if "model.context" not in settings:
        config = dataclasses.replace(
            config, model=dataclasses.replace(config.model, context=config.train.horizon)
        )
    return resolve_features(config, scale_steps="train.steps" not in given)  # the user's steps as given


def _features_setting(layers: tuple[dict, ...]) -> str:
    """model.features after the layers (later wins): a layer's own model.features, else "given" where the
    layer names a feature key (model.rls_order, ...), so explicit keys are not overwritten by an earlier
    layer's (or the preset's) auto; "" where no layer says anything."""
    features = ""
    for layer in layers:
        if "model.features" in layer:
            features = layer["model.features"]
        elif any(f"model.{key}" in layer for key in FEATURE_KEYS):
            features = "given"
    return features


__all__ = [
    "EXPERIMENTS",
    "PRESETS",
    "TEST_SEED_OFFSET",
    "Claim",
    "Condition",
    "Experiment",
    "Measure",
    "Preset",
    "get_experiment",
    "get_preset",
    "run_config",
]
