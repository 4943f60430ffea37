"""Reporting a finished experiment: its claims checked, figures, eval.json and report.md.

claims = [check_claim(c, results, exp.reference, seed) for c in exp.claims]
write_outputs(session, results, claims, stage, start)   # into a staging folder (mop.outputs)
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from mop.atomic import write_json, write_text
from mop.config import to_dict
from mop.experiments import TEST_SEED_OFFSET, get_preset, run_config
from mop.experiments.analyses import condition_sections, experiment_entries, experiment_sections
from mop.experiments.figures import FIGURES, figure_names
from mop.experiments.measures import describe, measure_value
from mop.experiments.planning import Session
from mop.experiments.results import ConditionResult, Results
from mop.experiments.spec import Claim, Experiment, Measure
from mop.identify import is_fitted
from mop.identify import load as load_fitted
from mop.predictors import first_learned
from mop.pretrained import resolve_run_dir
from mop.report import build_report, claim_line, fmt_ratio, has_interval, summary_section
from mop.runs import load_config
from mop.train import describe_features

OPS = {
    "<": lambda v, t: v < t,
    "<=": lambda v, t: v <= t,
    ">": lambda v, t: v > t,
    ">=": lambda v, t: v >= t,
    "between": lambda v, t: t[0] <= v <= t[1],
    "contains": lambda v, t: v[0] <= t <= v[1],
}


def check_claim(claim: Claim, results: Results, reference: str, seed: int) -> dict:
    """{"claim", "measure", "value", "threshold", "holds"} for one claim (holds None for op "info")."""
    learned = _first_learned(results)
    measure = learned(claim.measure)
    value = measure_value(measure, results, reference, seed)
    threshold = claim.threshold
    if isinstance(threshold, Measure):
        threshold = measure_value(learned(threshold), results, reference, seed)
    holds = None if claim.op == "info" or _nan(value) else bool(OPS[claim.op](value, threshold))
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


def best_table(exp: Experiment, results: Results) -> str:
    """The report's lead: MOP's ratio to the experiment's yardstick (exp.best_predictor: the optimum where one
    is known, else the predictor it names) per condition, beside the authors' number; the 95% interval only
    where there is more than one record to draw it from."""
    lines = [
        "## MOP against the yardstick",
        "",
        "| condition | yardstick | MOP / yardstick MSE ratio, t in [20,T] (95% CI) | the authors |",
        "|---|---|---|---|",
    ]
    for name, r in results.items():
        d = r.summary.get("to_best")
        if d:
            cell = fmt_ratio(d) if has_interval(d) else f"{d['ratio']:.3f} (one record: no interval)"
            lines.append(f"| {name} | {d['predictor']} | {cell} | {exp.authors or '-'} |")
    return "\n".join(lines) + "\n" if len(lines) > 4 else ""


def eval_entry(result: ConditionResult) -> dict:
    return {"condition": result.condition.name, **result.summary, **result.extras}


def write_outputs(session: Session, results: Results, claims: list[dict], out: Path, start: float) -> None:
    """Figures, eval.json and report.md of the finished experiment into `out` (the staging folder);
    start: time.perf_counter() when the experiment began (the report states the wall time since)."""
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
    sections = _sections(exp, results, figures) + experiment_sections(exp.analyses, entries)
    settings = {"seed": session.train_seed, "test seed": seed + TEST_SEED_OFFSET, **data["settings"]}
    title = f"mop reproduce {exp.name} ({exp.title}), preset {preset}"
    title += ", shipped pretrained weights" if session.pretrained else ""
    lines = [claim_text(c) for c in claims]
    seconds = time.perf_counter() - start
    text = build_report(title, sections, settings, lines, seconds, lead=best_table(exp, results))
    write_text(out / "report.md", text)


def evaluated_models(session: Session) -> dict[str, str]:
    """{predictor [condition]: what was evaluated}, read from each run's own config.json and done.json (a
    given, shipped or reused run is described as it was trained, not as the preset would train it)."""
    out = {}
    for key, run in session.runs.items():
        if is_fitted(run):
            fitted = load_fitted(run)
            out[key] = f"{run}: fitted {fitted.kind.upper()} {dict(fitted.orders)} (mop fit)"
            continue
        config = load_config(run)
        done = Path(resolve_run_dir(run)) / "done.json"
        steps = json.loads(done.read_text()).get("step", config.train.steps) if done.is_file() else None
        trained = (
            f"{steps} of {config.train.steps} steps" if steps is not None else f"{config.train.steps} steps"
        )
        m = config.model
        out[key] = f"{run}: {m.arch} {m.num_layers} x {m.width}, features {describe_features(m)}, {trained}"
    return out


def _settings(session: Session) -> dict:
    exp = session.exp
    trained = run_config(exp, session.preset, session.train_seed, overrides=session.overrides)
    evaluated = evaluated_models(session)
    learned = [k for k, run in session.runs.items() if not is_fitted(run)]
    if learned:  # the closing line's features: the first learned model's own, as it was trained
        config = load_config(session.runs[learned[0]])
        features = f"{describe_features(config.model)}, {config.train.steps} steps"
    else:
        features = f"{describe_features(trained.model)}, {trained.train.steps} steps"
    return {
        "evaluated": evaluated,
        "train": to_dict(trained),
        "features": features,
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
