"""The one generic runner: train (or reuse) the learned predictors, evaluate every condition, run the
analyses, check the claims, draw the figures, write eval.json and report.md.

    report = run_experiment(get_experiment("linear"), "small", Path("out/linear"), seed=0)

Three steps, one module each: planning (mop.experiments.planning: which predictors, which runs are trained,
reused, given or shipped), evaluating (mop.experiments.evaluating: one condition's test data, errors and
ratios, the function `mop pretrained build` measures its cards with too) and reporting
(mop.experiments.reporting: claims, figures, eval.json, report.md).
"""

from __future__ import annotations

import time
from pathlib import Path

from mop.experiments.analyses import ANALYSES
from mop.experiments.evaluating import evaluate_condition
from mop.experiments.planning import Session, condition_config, condition_predictors, resolve_given_runs
from mop.experiments.reporting import check_claim, write_outputs
from mop.experiments.results import ConditionResult
from mop.experiments.spec import Condition, Experiment
from mop.experiments.validate import validate_experiment
from mop.outputs import staged_output


def run_condition(session: Session, condition: Condition) -> ConditionResult:
    """One condition: its predictors (trained or loaded as planned), evaluated, then the analyses'
    extras (each analysis sees the result, the predictors and the reference)."""
    trained = condition_config(session, condition)  # built once: the runs, the test horizon and family
    predictors = condition_predictors(session, condition, trained)
    result = evaluate_condition(
        session.exp,
        condition,
        predictors,
        trained,
        preset=session.preset,
        seed=session.seed,
        progress=session.progress,
    )
    for analysis in session.exp.analyses:
        result.extras.update(ANALYSES.get(analysis)(result, predictors, session.exp.reference))
    return result


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
    pretrained: evaluate the shipped models instead of training (NoPretrainedModel first when one is
    missing).
    """
    validate_experiment(exp, preset, seed=seed, overrides=list(overrides), choices=choices)
    start = time.perf_counter()
    out = Path(out)
    runs_dir = Path(runs_dir or out.parent / "runs")
    session = Session(
        exp, preset, seed, runs_dir, list(overrides), progress, dict(choices or {}), pretrained, wait
    )
    session.train_seed = seed if train_seed is None else train_seed
    resolve_given_runs(session)  # given / shipped runs before any work
    results = {c.name: run_condition(session, c) for c in exp.conditions_for(preset)}
    claims = [check_claim(c, results, exp.reference, seed) for c in exp.claims]
    with staged_output(out) as stage:
        write_outputs(session, results, claims, stage, start)
    return out / "report.md"
