"""The one generic runner: train (or reuse) the learned predictors, evaluate every condition, run the
analyses, check the claims, draw the figures, write eval.json and report.md.

    report = run_experiment(get_experiment("linear"), "small", Path("out/linear"), seed=0)

Trained runs are shared by configuration: each lives in RUNS/<predictor>-<hash of its RunConfig>, with RUNS
the `runs` directory beside `out` unless given. Experiments (or conditions) that train the same config,
e.g. `switching` and `linear`, reuse one run; a finished run is never trained again.

Nothing is trained for a learned predictor given a run (an experiment's or condition's `runs`: a run
directory or `pretrained:NAME`), nor with pretrained=True (`mop reproduce --pretrained`), which evaluates the
shipped model trained on the condition's family (mop.pretrained.find_shipped); every such run is resolved
before any evaluation, so a missing one is a one-line error before any work.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mop.atomic import write_json, write_text
from mop.config import RunConfig, SystemConfig, apply_settings, to_dict
from mop.errors import MopError
from mop.evaluate import evaluate, summarize
from mop.experiments import TEST_SEED_OFFSET, get_preset, run_config
from mop.experiments.analyses import (
    ANALYSES,
    condition_sections,
    experiment_entries,
    experiment_sections,
)
from mop.experiments.figures import FIGURES, figure_names
from mop.experiments.measures import describe, measure_value
from mop.experiments.results import ConditionResult, Results
from mop.experiments.spec import Claim, Condition, Experiment, Measure
from mop.experiments.validate import evaluated, validate_experiment
from mop.io import read_trajectories
from mop.metrics import mse_ratio_ci
from mop.missing import drop_mask, drop_outputs
from mop.outputs import staged_output
from mop.predictors import PREDICTORS, first_learned, is_learned, make_predictor
from mop.pretrained import find_shipped, shipped_names
from mop.report import build_report, claim_line, summary_section
from mop.systems import generator, make_family
from mop.systems.base import Trajectories
from mop.train import describe_features, for_arch, train_model


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


LATE_WINDOW = (20, None)  # t in [20, T]: where the paper compares MOP with the optimal filter


def config_hash(config: RunConfig) -> str:
    """12 hex digits of SHA-256 over the config's canonical JSON: equal configs share a run directory."""
    return hashlib.sha256(json.dumps(to_dict(config), sort_keys=True).encode()).hexdigest()[:12]


def wanted(session: Session, condition: Condition) -> list[str]:
    """The predictors evaluated under `condition`: those an entry's skip_presets leave out under this preset
    only where `choices` (--with NAME) asks for them; `choices` False (--without NAME) drops one anywhere."""
    return evaluated(session.exp, session.preset, condition, session.choices)


def _with_arch(trained: RunConfig, name: str) -> RunConfig:
    return for_arch(trained, PREDICTORS.meta(name)["arch"])  # the GRU: no input features


def given_run(session: Session, name: str, condition: Condition, trained: RunConfig) -> str:
    """The run learned predictor `name` uses under `condition` without training ("" = train it): the
    condition's or experiment's `runs` entry, else with --pretrained the matching shipped model."""
    given = {**session.exp.runs, **condition.runs}.get(name, "")
    if given or not session.pretrained:
        return given
    config = _with_arch(trained, name)
    found = find_shipped(to_dict(config))
    if found is None:
        shipped = ", ".join(shipped_names()) or "none"
        raise MopError(
            f"{session.exp.name} [{condition.name}]: no pretrained model is shipped for {name} trained on "
            f"this condition's family ({config.system.family}, {config.model.readout} read-out; shipped: "
            f"{shipped}); run without --pretrained to train it"
        )
    return found


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


def training_run(session: Session, name: str, trained: RunConfig) -> tuple[RunConfig, str]:
    """(the RunConfig learned predictor `name` trains, its run directory RUNS/<name>-<config hash>)."""
    config = _with_arch(trained, name)
    return config, str(session.runs_dir / f"{name}-{config_hash(config)}")


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


def condition_config(session: Session, condition: Condition, arch: str = "gpt") -> RunConfig:
    """The RunConfig trained for `condition` (preset < experiment < condition < command-line overrides)."""
    return run_config(session.exp, session.preset, session.train_seed, arch, condition, session.overrides)


def test_system(trained: RunConfig, condition: Condition) -> SystemConfig:
    """The condition's test family: the trained family's config with the condition's overrides."""
    return apply_settings(trained.system, condition.system)


def test_trajectories(system: SystemConfig, num_systems: int, horizon: int, seed: int) -> Trajectories:
    """Seeded test systems (float64), apart from the training (seed) and validation streams."""
    family = make_family(system, dtype=torch.float64)
    return family.generate(num_systems, horizon, generator=generator(seed + TEST_SEED_OFFSET))


def recorded_trajectories(path: str, horizon: int) -> Trajectories:
    """The recordings of `path` with at least horizon + 1 outputs, cut to y_0..y_horizon (float64)."""
    _, data = read_trajectories(path)
    long = [(y, u) for y, u in data if len(y) > horizon]
    if not long:
        raise MopError(f"{path}: no trajectory has {horizon + 1} steps; lower the condition's horizon")
    y = torch.tensor(np.stack([y[: horizon + 1] for y, _ in long]), dtype=torch.float64)
    u = None if long[0][1] is None else np.stack([u[: horizon + 1] for _, u in long])
    return Trajectories(y=y, u=None if u is None else torch.tensor(u, dtype=torch.float64))


MISSING_SEED_OFFSET = 9_000_011  # the test drop-out masks: generator seed + this


def with_missing(traj: Trajectories, missing: dict[str, float], seed: int) -> Trajectories:
    """traj with outputs removed (NaN) as the condition's `missing` says; y_0 always kept; seeded."""
    g = torch.Generator(device=traj.y.device).manual_seed(seed + MISSING_SEED_OFFSET)
    drop = drop_mask(
        tuple(traj.y.shape),
        missing.get("rate", 0.0),
        g,
        missing.get("burst_rate", 0.0),
        int(missing.get("burst_length", 5)),
    )
    return dataclasses.replace(traj, y=drop_outputs(traj.y, drop))


def run_condition(session: Session, condition: Condition) -> ConditionResult:
    exp, preset = session.exp, get_preset(session.preset)
    trained = condition_config(session, condition)  # built once: the runs, the test horizon and family
    predictors = []
    for name in wanted(session, condition):
        if is_learned(name):
            predictors.append(learned_predictor(session, name, condition, trained))
        else:
            per_preset = PREDICTORS.meta(name).get("preset_options", {})  # the entry's own options
            options = per_preset.get(session.preset, {})
            predictors.append(make_predictor(name, shared={"seed": session.seed}, **options))
    horizon = condition.horizon or trained.train.horizon  # with the command line's overrides, like the run
    if condition.data:
        traj = recorded_trajectories(condition.data, horizon)
    else:
        traj = test_trajectories(
            test_system(trained, condition), preset.num_test_systems, horizon, session.seed
        )
    if condition.missing:
        traj = with_missing(traj, condition.missing, session.seed)
    raw = evaluate(predictors, traj, session.progress)
    summary = summarize(raw, reference=exp.reference, seed=session.seed)
    summary["to_best"] = distance_to_best(raw, exp.best_predictor, session.seed)
    result = ConditionResult(condition, traj, {k: v["e"] for k, v in raw.items()}, summary)
    for analysis in exp.analyses:
        result.extras.update(ANALYSES.get(analysis)(result, predictors, exp.reference))
    return result


def distance_to_best(raw: dict, best: str, seed: int, model: str = "") -> dict | None:
    """MOP's MSE ratio to the best predictor over t in [20, T] with its bootstrap CI (None if either is
    missing from the condition): {"predictor", "window", "ratio", "low", "high"}."""
    model = model or next((n for n in raw if n in PREDICTORS and is_learned(n)), "")  # "": the first learned
    if model not in raw or best not in raw:
        return None
    e_mop, e_best = raw[model]["e"], raw[best]["e"]
    start, stop = LATE_WINDOW[0], e_mop.shape[1]
    if stop <= start:
        return None
    ratio, low, high = mse_ratio_ci(e_mop, e_best, start, stop, seed=seed)
    return {"predictor": best, "window": [start, stop], "ratio": ratio, "low": low, "high": high}


def best_table(exp: Experiment, results: Results) -> str:
    """The report's lead: MOP's ratio to the best predictor per condition, beside the authors' number."""
    lines = [
        "## Distance to the best predictor",
        "",
        "| condition | best predictor | MOP / best MSE ratio, t in [20,T] (95% CI) | the authors |",
        "|---|---|---|---|",
    ]
    for name, r in results.items():
        d = r.summary.get("to_best")
        if d:
            cell = f"{d['ratio']:.3f} [{d['low']:.3f}, {d['high']:.3f}]"
            lines.append(f"| {name} | {d['predictor']} | {cell} | {exp.authors or '-'} |")
    return "\n".join(lines) + "\n" if len(lines) > 4 else ""


def check_claim(claim: Claim, results: Results, reference: str, seed: int) -> dict:
    """{"claim", "measure", "value", "threshold", "holds"} for one claim (holds None for op "info")."""
    learned = _first_learned(results)
    measure = learned(claim.measure)
    value = measure_value(measure, results, reference, seed)
    threshold = claim.threshold
    if isinstance(threshold, Measure):
        threshold = measure_value(learned(threshold), results, reference, seed)
    ops = {
        "<": lambda v, t: v < t,
        "<=": lambda v, t: v <= t,
        ">": lambda v, t: v > t,
        ">=": lambda v, t: v >= t,
        "between": lambda v, t: t[0] <= v <= t[1],
        "contains": lambda v, t: v[0] <= t <= v[1],
    }
    holds = None if claim.op == "info" or _nan(value) else bool(ops[claim.op](value, threshold))
    return {
        "claim": claim.text,
        "measure": describe(measure, reference),
        "value": value,
        "op": claim.op,
        "threshold": threshold,
        "holds": holds,
    }


def _first_learned(results: Results):
    """Measure -> the measure with its predictor, "" standing for the results' first learned predictor."""
    names = [n for r in results.values() for n in r.errors]

    def resolve(measure: Measure) -> Measure:
        if measure.predictor:
            return measure
        return dataclasses.replace(measure, predictor=first_learned(dict.fromkeys(names)))

    return resolve


def _nan(value) -> bool:
    return any(np.isnan(v) for v in (value if isinstance(value, tuple) else (value,)))


def _fmt(value) -> str:
    if isinstance(value, (tuple, list)):
        return "[" + ", ".join(f"{v:.4g}" for v in value) + "]"
    return f"{value:.4g}"


def claim_text(c: dict) -> str:
    threshold = "" if c["op"] == "info" else f" {c['op']} {_fmt(c['threshold'])}"
    return claim_line(c["claim"], f"{c['measure']} = {_fmt(c['value'])}{threshold}", c["holds"])


def eval_entry(result: ConditionResult) -> dict:
    return {"condition": result.condition.name, **result.summary, **result.extras}


def run_experiment(
    exp: Experiment,
    preset: str,
    out: Path,
    *,
    seed: int = 0,
    runs_dir: Path | None = None,
    overrides: list[str] = (),
    progress: bool = True,
    choices: dict[str, bool] | None = None,
    pretrained: bool = False,
    wait: bool = True,
    train_seed: int | None = None,
) -> Path:
    """Run `exp` under `preset` into `out` (eval.json, figures, report.md); returns report.md's path.

    choices: predictor -> True to evaluate it where its skip_presets would leave it out (--with NAME),
    False to leave it out (--without NAME).
    seed: the test systems' seed (seed + TEST_SEED_OFFSET) and, unless train_seed is given, train.seed.
    The experiment is validated first (mop.experiments.validate), so a mistake costs seconds, not a
    training run. The files are written all or nothing (mop.outputs): a stopped run leaves the previous
    output whole; `complete.json`, written last, lists them. wait: see mop.train.train.
    pretrained: evaluate the shipped models instead of training (MopError first when one is missing).
    """
    validate_experiment(exp, preset, seed=seed, overrides=list(overrides), choices=choices)
    start = time.perf_counter()
    out = Path(out)
    runs_dir = Path(runs_dir or out.parent / "runs")
    session = Session(
        exp, preset, seed, runs_dir, list(overrides), progress, dict(choices or {}), pretrained, wait
    )
    session.train_seed = seed if train_seed is None else train_seed
    for condition in exp.conditions_for(preset):  # resolve given / shipped runs before any work
        trained = condition_config(session, condition)
        for name in wanted(session, condition):
            if is_learned(name):
                given_run(session, name, condition, trained)
    results = {c.name: run_condition(session, c) for c in exp.conditions_for(preset)}
    claims = [check_claim(c, results, exp.reference, seed) for c in exp.claims]
    with staged_output(out) as stage:
        _write_outputs(session, results, claims, stage, start)
    return out / "report.md"


def _write_outputs(session: Session, results: dict, claims: list[dict], out: Path, start: float) -> None:
    """Figures, eval.json and report.md of the finished experiment into `out` (the staging folder)."""
    exp, preset, seed = session.exp, session.preset, session.seed
    figures = [p for name in figure_names(exp) for p in FIGURES.get(name)(exp, results, out)]
    first = next(iter(results.values()))
    entries = experiment_entries(exp.analyses, results)  # e.g. the sweeps' fits
    data = {
        "experiment": exp.name,
        "title": exp.title,
        "preset": preset,
        "seed": seed,
        "train_seed": session.train_seed,
        **first.summary,
        "conditions": {name: eval_entry(r) for name, r in results.items()},
        **entries,
        "claims": claims,
        "runs": session.runs,
        "settings": _settings(session),
    }
    write_json(out / "eval.json", data)
    sections = _sections(exp, results, figures)
    sections += experiment_sections(exp.analyses, entries)
    settings = {
        "seed": session.train_seed,
        "test seed": seed + TEST_SEED_OFFSET,
        **data["settings"],
    }
    title = f"mop reproduce {exp.name} ({exp.title}), preset {preset}"
    title += ", shipped pretrained weights" if session.pretrained else ""
    text = build_report(
        title,
        sections,
        settings,
        [claim_text(c) for c in claims],
        time.perf_counter() - start,
        lead=best_table(exp, results),
    )
    write_text(out / "report.md", text)


def _settings(session: Session) -> dict:
    exp = session.exp
    trained = run_config(exp, session.preset, session.train_seed, overrides=session.overrides)
    return {
        "train": to_dict(trained),
        "features": f"{describe_features(trained.model)}, {trained.train.steps} steps",
        "overrides": session.overrides,
        "conditions": [dataclasses.asdict(c) for c in exp.conditions_for(session.preset)],
        "num_test_systems": get_preset(session.preset).num_test_systems,
        "pretrained": session.pretrained,
        "predictors": list(exp.predictors),
        "reference": exp.reference,
    }


def _sections(exp: Experiment, results: Results, figures: list[Path]) -> list[str]:
    pngs = [f.name for f in figures if f.suffix == ".png"]
    sections = []
    if exp.description:
        sections.append(exp.description[0].upper() + exp.description[1:] + ".\n")
    for name, r in results.items():
        heading = exp.name if len(results) == 1 else f"{exp.name}: {name}"
        mine = [f for f in pngs if len(results) == 1 or name.replace(" ", "_") in f]
        sections.append(summary_section(heading, r.summary, mine))
        sections += condition_sections(exp.analyses, r.extras)  # each analysis renders its own table
    shared = [f for f in pngs if not any(f in s for s in sections)]
    if shared:
        sections.append("\n".join(f"![{f}]({f})" for f in shared))
    return sections
