"""Planning an experiment: which predictors each condition evaluates, which runs they train or load.

Trained runs are shared by configuration: each lives in RUNS/<predictor>-<hash of its RunConfig>, with RUNS
the `runs` directory beside `out` unless given. Experiments (or conditions) that train the same config,
e.g. `switching` and `linear`, reuse one run; a finished run is never trained again.

Nothing is trained for a learned predictor given a run (an experiment's or condition's `runs`: a run
directory or `pretrained:NAME`), nor with pretrained=True (`mop reproduce --pretrained`), which evaluates the
shipped model trained on the condition's family (mop.pretrained.find_shipped); every such run is resolved
before any evaluation (resolve_given_runs), so a missing one is a one-line error before any work.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path
from typing import Any

from mop.config import ModelConfig, RunConfig, SystemConfig, to_dict
from mop.errors import MopError, NoPretrainedModel
from mop.experiments import run_config
from mop.experiments.evaluating import test_system
from mop.experiments.spec import Condition, Experiment
from mop.experiments.validate import evaluated
from mop.identify import is_fitted
from mop.identify import load as load_fitted
from mop.models.registry import predictor_names
from mop.predictors import PREDICTORS, is_learned, make_predictor
from mop.pretrained import find_shipped, shipped_names
from mop.runs import load_predictor
from mop.train import for_arch, train_model


@dataclasses.dataclass
class Session:
    """What one `run_experiment` call shares across conditions: settings and the loaded learned models."""

    exp: Experiment
    preset: str
    seed: int
    runs_dir: Path
    overrides: list[str]
    progress: bool
    choices: dict[str, bool]  # predictor -> forced in (True) or out (False), over its skip_presets
    pretrained: bool = False
    wait: bool = True
    train_seed: int = 0  # train.seed of the learned predictors; `seed` seeds the test systems
    loaded: dict[str, Any] = dataclasses.field(default_factory=dict)
    runs: dict[str, str] = dataclasses.field(default_factory=dict)


def config_hash(config: RunConfig) -> str:
    """12 hex digits of SHA-256 over the config's canonical JSON: equal configs share a run directory."""
    return hashlib.sha256(json.dumps(to_dict(config), sort_keys=True).encode()).hexdigest()[:12]


def wanted(session: Session, condition: Condition) -> list[str]:
    """The predictors evaluated under `condition`: those an entry's skip_presets leave out under this preset
    only where `choices` (--with NAME) asks for them; `choices` False (--without NAME) drops one anywhere."""
    return evaluated(session.exp, session.preset, condition, session.choices)


def condition_config(session: Session, condition: Condition, arch: str = "gpt") -> RunConfig:
    """The RunConfig trained for `condition` (preset < experiment < condition < command-line overrides)."""
    return run_config(session.exp, session.preset, session.train_seed, arch, condition, session.overrides)


def classical_predictor(name: str, preset: str, seed: int, system: SystemConfig | None = None):
    """Classical predictor `name` with the options its registry entry gives under `preset` (preset_options,
    e.g. n4sid-kf re-identifying every 10 steps on the CPU presets), the seed and the test systems' family
    config `system` (the Bayes predictor over the family), where it takes them."""
    per_preset = PREDICTORS.meta(name).get("preset_options", {})  # the entry's own options
    return make_predictor(name, shared={"seed": seed, "system": system}, **per_preset.get(preset, {}))


def _with_arch(trained: RunConfig, name: str) -> RunConfig:
    """The RunConfig learned predictor `name` trains. The experiment's own learned slot (mop, the
    transformer's predictor) trains the architecture its layers give (the transformer unless one names
    model.arch: a records start's deep LRU, as `mop pretrained build` trains it); another learned slot
    (gru, deep-lru) its own architecture, without the input features where it reads none."""
    arch = PREDICTORS.meta(name)["arch"]
    return trained if name == predictor_names()[ModelConfig.arch] else for_arch(trained, arch)


def given_run(session: Session, name: str, condition: Condition, trained: RunConfig) -> str:
    """The run learned predictor `name` uses under `condition` without training ("" = train it): the
    condition's or experiment's `runs` entry, else with --pretrained the matching shipped model
    (NoPretrainedModel when none is shipped)."""
    given = {**session.exp.runs, **condition.runs}.get(name, "")
    if given or not session.pretrained:
        return given
    config = _with_arch(trained, name)
    found = find_shipped(to_dict(config), experiment=session.exp.name)
    if found is None:
        shipped = ", ".join(shipped_names()) or "none"
        raise NoPretrainedModel(
            f"{session.exp.name} [{condition.name}]: no pretrained model is shipped for {name} trained on "
            f"this condition's family ({config.system.family}, {config.model.readout} read-out; shipped: "
            f"{shipped}); run without --pretrained to train it"
        )
    return found


def resolve_given_runs(session: Session) -> None:
    """Look up every given or shipped run of the experiment before any work (NoPretrainedModel first); a
    `runs` entry naming a predictor that no condition evaluates is refused (it would be silently unused)."""
    conditions = session.exp.conditions_for(session.preset)
    evaluated_anywhere = {name for c in conditions for name in wanted(session, c)}
    for where, runs in [("[runs]", session.exp.runs), *((f"[{c.name}] runs", c.runs) for c in conditions)]:
        unused = sorted(set(runs) - evaluated_anywhere)
        if unused:
            raise MopError(
                f"{session.exp.name}: {where} names {', '.join(repr(u) for u in unused)}, which no condition "
                f"evaluates (predictors: {', '.join(sorted(evaluated_anywhere))}); add it to the predictors "
                "or remove the entry"
            )
    for condition in conditions:
        trained = condition_config(session, condition)
        for name in wanted(session, condition):
            if is_learned(name):
                given_run(session, name, condition, trained)
            else:
                given = {**session.exp.runs, **condition.runs}.get(name, "")
                if given and given not in session.loaded:
                    session.loaded[given] = given_classical(name, given)
                if given:
                    session.runs[f"{name} [{condition.name}]"] = given  # the report's provenance


def given_classical(name: str, path: str):
    """The predictor a `runs` entry gives for classical name `name`: a fitted model's directory (mop fit),
    a run directory or pretrained:NAME, loaded as `mop predict` loads it and named `name` in the report."""
    if is_fitted(path):
        predictor = load_fitted(path)
    elif path.startswith("pretrained:") or Path(path, "config.json").is_file():
        predictor = load_predictor(path)
    else:
        raise MopError(f"runs: {name} = {path!r} is neither a fitted model (mop fit) nor a run directory")
    predictor.name = name
    return predictor


def training_run(session: Session, name: str, trained: RunConfig) -> tuple[RunConfig, str]:
    """(the RunConfig learned predictor `name` trains, its run directory RUNS/<name>-<config hash>)."""
    config = _with_arch(trained, name)
    return config, str(session.runs_dir / f"{name}-{config_hash(config)}")


def learned_predictor(session: Session, name: str, condition: Condition, trained: RunConfig):
    """Train (or reuse) the run of learned predictor `name` for `condition` (its RunConfig `trained`, with
    the predictor's architecture), or take its given / shipped run. A run trained here is handed over by the
    trainer (no reload); a given, shipped or finished run is loaded once."""
    run = given_run(session, name, condition, trained)
    if run:
        if run not in session.loaded:
            session.loaded[run] = make_predictor(name, run_dir=run)
    else:
        config, run = training_run(session, name, trained)
        if run not in session.loaded:
            model = train_model(config, run, progress=session.progress, wait=session.wait)
            session.loaded[run] = make_predictor(name, run_dir=run, model=model)
    session.runs[f"{name} [{condition.name}]"] = run
    return session.loaded[run]


def condition_predictors(session: Session, condition: Condition, trained: RunConfig) -> list:
    """The predictors `condition` evaluates, in the experiment's order: learned ones trained, reused or
    loaded (learned_predictor), classical ones built with the test seed (classical_predictor)."""
    return [
        learned_predictor(session, name, condition, trained)
        if is_learned(name)
        else session.loaded[given]
        if (given := {**session.exp.runs, **condition.runs}.get(name, ""))
        else classical_predictor(name, session.preset, session.seed, test_system(trained, condition))
        for name in wanted(session, condition)
    ]


def planned_runs(
    exp: Experiment,
    preset: str,
    *,
    seed: int,
    train_seed: int,
    runs_dir: Path,
    overrides: list[str] = (),
    choices: dict[str, bool] | None = None,
) -> list[tuple[RunConfig, str]]:
    """The (config, run directory) of every run `run_experiment` with these arguments trains (not those it
    is given), each once, in the order it needs them; `mop reproduce --jobs` trains them ahead."""
    session = Session(exp, preset, seed, Path(runs_dir), list(overrides), False, dict(choices or {}))
    session.train_seed = train_seed
    runs: dict[str, RunConfig] = {}
    for condition in exp.conditions_for(preset):
        trained = condition_config(session, condition)
        for name in wanted(session, condition):
            if is_learned(name) and not given_run(session, name, condition, trained):
                config, run = training_run(session, name, trained)
                runs.setdefault(run, config)
    return [(config, run) for run, config in runs.items()]
