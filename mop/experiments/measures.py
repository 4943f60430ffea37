"""Measures: the numbers a Claim reads from an experiment's results, each a registered function.

    value = measure_value(Measure("mse_ratio", window=(20, None)), results, reference="kalman", seed=0)

`results` maps condition name -> ConditionResult (mop.experiments.results). A measure returns a float or,
for interval measures (the slope's 95% CI), a (low, high) pair. Its registry metadata describes it:
    describe(measure, reference) -> str   its name in report.md (default: the metric and the condition)
    over_conditions=True                  it reads every condition's results, fn(measure, results, ...)
    interval=True                         it returns a (low, high) pair (op "contains")
    needs="ANALYSIS"                      it reads that analysis's extras (checked before training)
    reads_reference=True                  it reads the reference's errors too
This module holds the measures of the predictors' errors; those that read an analysis's extras
(coverage, matrix_power_max, slope) are registered beside their analysis in mop.experiments.analyses.
"""

from __future__ import annotations

import numpy as np

from mop.errors import MopError
from mop.experiments.results import ConditionResult, Results
from mop.experiments.spec import Measure
from mop.metrics import mse_ratio_ci
from mop.registry import Registry

MEASURES: Registry = Registry(
    "measure",
    keys={
        "describe": "(measure, value) -> the claim's text",
        "reads_reference": "compares with a reference predictor (its `reference`, else the experiment's)",
        "needs": "the analysis whose results it reads",
        "over_conditions": "measured across the conditions of a sweep axis",
        "interval": "its value has a confidence interval",
    },
)


def _span(measure: Measure, horizon: int) -> tuple[int, int]:
    start, stop = measure.window
    return start, min(horizon + 1, stop if stop is not None else horizon + 1)


def _errors(result: ConditionResult, name: str) -> np.ndarray:
    if name not in result.errors:
        raise MopError(
            f"condition {result.condition.name!r} has no predictor {name!r} "
            f"(it has {', '.join(result.errors)})"
        )
    return result.errors[name]


def where(measure: Measure) -> str:
    """The suffix " [condition]" of a measure on a named condition, else the empty string."""
    return f" [{measure.condition}]" if measure.condition else ""


def window_text(measure: Measure) -> str:
    start, stop = measure.window
    return f"t in [{start},{'T' if stop is None else stop})"


def _mse_ratio_text(measure: Measure, reference: str) -> str:
    bound = "" if measure.bound == "ratio" else f" (CI {measure.bound})"
    return (
        f"MSE {measure.predictor}/{measure.reference or reference} over {window_text(measure)}{bound}"
        f"{where(measure)}"
    )


def _mean_error_text(measure: Measure, reference: str) -> str:
    return f"mean error of {measure.predictor} over {window_text(measure)}{where(measure)}"


@MEASURES.register("mse_ratio", describe=_mse_ratio_text, reads_reference=True)
def mse_ratio(measure: Measure, result: ConditionResult, reference: str, seed: int) -> float:
    e_num, e_den = _errors(result, measure.predictor), _errors(result, measure.reference or reference)
    ratio, low, high = mse_ratio_ci(e_num, e_den, *_span(measure, e_num.shape[1] - 1), seed=seed)
    return {"ratio": ratio, "low": low, "high": high}[measure.bound]


@MEASURES.register("mean_error", describe=_mean_error_text)
def mean_error(measure: Measure, result: ConditionResult, reference: str, seed: int) -> float:
    e = _errors(result, measure.predictor)
    start, stop = _span(measure, e.shape[1] - 1)
    part = e[:, start:stop]
    return float(np.nanmean(part) if np.isnan(part).any() else part.mean())  # NaN: nothing measured


def _rmse_text(measure: Measure, reference: str) -> str:
    return f"one-step RMSE of {measure.predictor} over {window_text(measure)}{where(measure)}"


@MEASURES.register("rmse", describe=_rmse_text)
def rmse(measure: Measure, result, reference: str, seed: int) -> float:
    """Mean over systems of each system's RMSE over t in `window` and the outputs (Forgione et al.'s
    metrics.rmse over time, then the mean over sequences)."""
    e = _errors(result, measure.predictor)  # (N, T+1) ||e_t||
    start, stop = _span(measure, e.shape[1] - 1)
    m = result.traj.output_dim
    return float(np.sqrt((e[:, start:stop] ** 2).mean(1) / m).mean())


def measure_value(
    measure: Measure, results: Results, reference: str, seed: int
) -> float | tuple[float, float]:
    """Evaluate `measure` on the results (one condition, or every one reduced by max/min)."""
    fn = MEASURES.get(measure.metric)
    if MEASURES.meta(measure.metric).get("over_conditions"):
        return fn(measure, results, reference, seed)
    if measure.condition == "*":
        values = [fn(measure, r, reference, seed) for r in results.values() if measure.predictor in r.errors]
        return max(values) if measure.reduce == "max" else min(values)
    name = measure.condition or next(iter(results))
    if name not in results:
        raise MopError(f"measure {measure.metric}: no condition {name!r} (have {', '.join(results)})")
    return fn(measure, results[name], reference, seed)


def describe(measure: Measure, reference: str) -> str:
    """A short human name of the measure for the report (the entry's own `describe`)."""
    text = MEASURES.meta(measure.metric).get("describe")
    return text(measure, reference) if text else f"{measure.metric}{where(measure)}"
