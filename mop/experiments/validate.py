"""Check an experiment completely before anything is trained: every problem is one MopError, in seconds.

    validate_experiment(exp, "small", overrides=["train.steps=100"])

What run_experiment would otherwise find only after training and evaluation (with the paper preset, hours
later): every name resolved in its registry (predictors, the reference, the panel, analyses, figures,
measures, model architectures, system families), every condition's training config and test system built
(so their values are typed and in range), recorded-data files present, and every claim's measure typed and
pointing at something that will exist: its predictors evaluated in its condition, its window inside the
condition's horizon T, its sweep axis placed by some condition, the analysis it reads requested.
"""

from __future__ import annotations

import os
from pathlib import Path

from mop.config import RunConfig, apply_settings
from mop.errors import MopError
from mop.experiments import get_preset, run_config
from mop.experiments.analyses import ANALYSES
from mop.experiments.figures import FIGURES, figure_names
from mop.experiments.measures import MEASURES
from mop.experiments.spec import Claim, Condition, Experiment, Measure
from mop.models import check_arch
from mop.predictors import PREDICTORS, is_learned, needs_system
from mop.systems import make_family


def evaluated(
    exp: Experiment, preset: str, condition: Condition, choices: dict[str, bool] | None = None
) -> list[str]:
    """The predictors evaluated under `condition`: those an entry's skip_presets leave out under this preset
    only where `choices` (--with NAME) asks for them; `choices` False (--without NAME) drops one anywhere; no
    predictor that needs the system on recorded data."""
    names = [n for n in condition.predictors or exp.predictors if _included(preset, choices or {}, n)]
    return [n for n in names if not (condition.data and needs_system(n))]  # recordings carry no system


def _included(preset: str, choices: dict[str, bool], name: str) -> bool:
    if name in choices:
        return choices[name]
    return preset not in PREDICTORS.meta(name).get("skip_presets", ())


def validate_experiment(
    exp: Experiment,
    preset: str,
    *,
    seed: int = 0,
    overrides: list[str] = (),
    choices: dict[str, bool] | None = None,
) -> None:
    """MopError (one line, naming the experiment and the field) for anything that would fail later."""
    try:
        _validate(exp, preset, seed, list(overrides), dict(choices or {}))
    except MopError as err:
        text, head = str(err), f"experiment {exp.name}"
        raise MopError(text if text.startswith(head) else f"{head}: {text}") from None


def _validate(exp: Experiment, preset: str, seed: int, overrides: list[str], choices: dict) -> None:
    get_preset(preset)
    for name in choices:
        _predictor(name, "--with/--without: ")
    for name in (*exp.predictors, exp.reference, *(p for p in exp.panel if p)):
        _predictor(name, "")
    for name in exp.analyses:
        ANALYSES.get(name)
    for name in figure_names(exp):
        FIGURES.get(name)
    _experiment_train(exp, preset, seed, overrides)
    conditions = exp.conditions_for(preset)
    horizons, names = {}, {}
    for condition in conditions:
        horizons[condition.name] = _condition(exp, preset, seed, overrides, condition)
        names[condition.name] = evaluated(exp, preset, condition, choices)
        if not names[condition.name]:
            raise MopError(f"condition {condition.name!r} evaluates no predictor")
    for i, claim in enumerate(exp.claims):
        where = f"claims[{i}] ({claim.text!r})"
        _measure(exp, claim.measure, horizons, names, f"{where}.measure")
        if isinstance(claim.threshold, Measure):
            _measure(exp, claim.threshold, horizons, names, f"{where}.threshold")
        _claim_shape(claim, where)


def _experiment_train(exp: Experiment, preset: str, seed: int, overrides: list[str]) -> None:
    """The experiment's own [train] (and per-preset) settings, then the command line's key=value overrides,
    built before any condition's: a mistake there is blamed on where it was written, not on a condition."""
    try:
        run_config(exp, preset, seed)
    except MopError as err:
        raise MopError(f"[train]: {err}") from None
    try:
        run_config(exp, preset, seed, overrides=overrides)
    except MopError as err:
        raise MopError(f"key=value overrides: {err}") from None


def _predictor(name: str, where: str) -> None:
    if name not in PREDICTORS:
        known = ", ".join(PREDICTORS.names())
        raise MopError(f"{where}unknown predictor {name!r}; choose one of {known}")


def _condition(exp: Experiment, preset: str, seed: int, overrides: list[str], condition: Condition) -> int:
    """Build the condition's training configs and test system (their own checks run); its horizon T."""
    where = f"condition {condition.name!r}: "
    for name in condition.predictors:
        _predictor(name, where)
    try:
        config = run_config(exp, preset, seed, "gpt", condition, overrides)
        for name in {*exp.predictors, *condition.predictors}:
            if is_learned(name):
                check_arch(PREDICTORS.meta(name)["arch"])
                run_config(exp, preset, seed, PREDICTORS.meta(name)["arch"], condition, overrides)
        _training_source(config)
        make_family(apply_settings(config.system, condition.system))
        _forecast_heads(exp, config, condition.horizon or config.train.horizon)
    except MopError as err:
        raise MopError(f"{where}{err}") from None
    if condition.data and not Path(condition.data).is_file():
        raise MopError(f"{where}data file {condition.data} does not exist")
    return condition.horizon or config.train.horizon


def _forecast_heads(exp: Experiment, config: RunConfig, horizon: int) -> None:
    """A model that forecasts by its k-step heads has one for every step an analysis forecasts (the
    analyses registered with forecast_steps: horizon -> K)."""
    model = config.model
    if model.forecast_mode != "direct":
        return
    for name in exp.analyses:
        steps = ANALYSES.meta(name).get("forecast_steps", lambda horizon: 0)(horizon)
        if model.horizons < steps:
            raise MopError(
                f"the {name} analysis forecasts {steps} steps, but model.horizons={model.horizons} "
                f"(model.forecast_mode=direct) has heads for {model.horizons}; set model.horizons={steps}"
            )


def _training_source(config: RunConfig) -> None:
    """The family (or the recorded data file) the run trains on exists."""
    if config.data is not None:
        if not os.path.isfile(config.data.path):
            raise MopError(f"train data.path {config.data.path} does not exist")
        return
    make_family(config.system)


def _measure(exp: Experiment, m: Measure, horizons: dict, names: dict, where: str) -> None:
    if m.metric not in MEASURES:
        known = ", ".join(MEASURES.names())
        raise MopError(f"{where}: unknown metric {m.metric!r}; choose one of {known}")
    meta = MEASURES.meta(m.metric)  # what the measure reads: its registry metadata
    needed = meta.get("needs")
    if needed and needed not in exp.analyses:
        raise MopError(f"{where}: metric {m.metric!r} needs the {needed!r} analysis; add it to analyses")
    if meta.get("over_conditions"):
        axes = {c.x[0] for c in exp.conditions if c.x}
        if m.axis not in axes:
            raise MopError(f"{where}: no condition lies on the sweep axis {m.axis!r} (axes: {sorted(axes)})")
        return
    if m.condition not in ("", "*") and m.condition not in horizons:
        raise MopError(f"{where}: no condition {m.condition!r} (have {', '.join(horizons)})")
    chosen = list(horizons) if m.condition == "*" else [m.condition or next(iter(horizons))]
    predictor = m.predictor or _first_learned(names[chosen[0]], where)
    uses = {predictor, *([m.reference or exp.reference] if meta.get("reads_reference") else [])}
    for name in uses:
        _predictor(name, f"{where}: ")
        if not any(name in names[c] for c in chosen):
            raise MopError(
                f"{where}: predictor {name!r} is not evaluated in condition {chosen[0]!r} "
                f"(it evaluates {', '.join(names[chosen[0]])})"
            )
    start = m.window[0]
    for c in chosen:
        if start > horizons[c]:
            raise MopError(
                f"{where}: window {list(m.window)} starts beyond T = {horizons[c]} of condition {c!r}; "
                f"use a window inside [0, {horizons[c] + 1})"
            )


def _first_learned(names: list[str], where: str) -> str:
    learned = [n for n in names if is_learned(n)]
    if not learned:
        raise MopError(f"{where}: no learned predictor to measure; name the measure's predictor")
    return learned[0]


def _claim_shape(claim: Claim, where: str) -> None:
    interval = bool(MEASURES.meta(claim.measure.metric).get("interval"))
    if claim.op == "contains" and not interval:
        metric = claim.measure.metric
        raise MopError(f"{where}: op 'contains' needs an interval measure, not {metric!r}")
    if interval and claim.op not in ("contains", "info"):
        raise MopError(f"{where}: the slope measure is an interval; use op 'contains' or 'info'")
