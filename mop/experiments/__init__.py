"""Experiments: the paper's figures (and what goes beyond them) as data, plus the presets that size them.

    exp = get_experiment("linear")                  # or load_experiment("my_experiment.toml")
    config = run_config(exp, "small", seed=0)       # the RunConfig that trains its MOP
    settings = get_preset("small")                  # num_test_systems, ...

A new experiment is one registered Experiment (EXPERIMENTS.add) or one TOML/JSON file; `mop reproduce`
runs either through the one generic runner (mop.experiments.runner).
"""

from __future__ import annotations

import dataclasses
from typing import Any

from mop.config import DataConfig, RunConfig, apply_overrides
from mop.experiments.presets import PRESETS, Preset, get_preset
from mop.experiments.spec import Claim, Condition, Experiment, Measure
from mop.registry import Registry

TEST_SEED_OFFSET = 7_000_001  # test systems: generator seed + this, apart from training (seed) and validation


def _load_builtin() -> None:
    from mop.experiments.missing_data import MISSING_DATA
    from mop.experiments.paper import PAPER_EXPERIMENTS

    for exp in (*PAPER_EXPERIMENTS, MISSING_DATA):
        EXPERIMENTS.add(exp.name, exp)


EXPERIMENTS: Registry = Registry("experiment", loader=_load_builtin, group="mop.experiments")


def get_experiment(name: str) -> Experiment:
    return EXPERIMENTS.get(name)


def overrides_list(overrides: dict[str, Any]) -> list[str]:
    """{"train.steps": 5} -> ["train.steps=5"] (values JSON-encoded, as on the command line)."""
    import json

    return [f"{k}={json.dumps(v)}" for k, v in overrides.items()]


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
    The model's context is the training horizon unless a layer sets it.
    """
    p = get_preset(preset)
    base = RunConfig(
        model=dataclasses.replace(p.model, arch=arch), train=dataclasses.replace(p.train, seed=seed)
    )
    layers = {**exp.train, **exp.presets.get(preset, {}), **(condition.train if condition else {})}
    if "data.path" in layers:  # trained on recorded trajectories (mop train --data)
        base = dataclasses.replace(base, data=DataConfig(path=layers["data.path"]))
    config = apply_overrides(base, overrides_list(layers) + list(overrides))
    if "model.context" not in layers and not any(o.startswith("model.context=") for o in overrides):
        config = dataclasses.replace(
            config, model=dataclasses.replace(config.model, context=config.train.horizon)
        )
    return config


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
