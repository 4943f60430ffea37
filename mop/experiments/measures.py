"""Measures: the numbers a Claim reads from an experiment's results, each a registered function.

    value = measure_value(Measure("mse_ratio", window=(20, None)), results, reference="kalman", seed=0)

`results` maps condition name -> ConditionResult (mop.experiments.runner). A measure returns a float or,
for interval measures (the slope's 95% CI), a (low, high) pair.
"""

from __future__ import annotations

import numpy as np

from mop.errors import MopError
from mop.experiments.results import ConditionResult, Results
from mop.experiments.spec import Measure
from mop.metrics import loglog_slope, mse_ratio_ci
from mop.registry import Registry

MEASURES: Registry = Registry("measure")


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


@MEASURES.register("mse_ratio")
def mse_ratio(measure: Measure, result: ConditionResult, reference: str, seed: int) -> float:
    e_num, e_den = _errors(result, measure.predictor), _errors(result, measure.reference or reference)
    ratio, low, high = mse_ratio_ci(e_num, e_den, *_span(measure, e_num.shape[1] - 1), seed=seed)
    return {"ratio": ratio, "low": low, "high": high}[measure.bound]


@MEASURES.register("mean_error")
def mean_error(measure: Measure, result: ConditionResult, reference: str, seed: int) -> float:
    e = _errors(result, measure.predictor)
    start, stop = _span(measure, e.shape[1] - 1)
    part = e[:, start:stop]
    return float(np.nanmean(part) if np.isnan(part).any() else part.mean())  # NaN: nothing measured


@MEASURES.register("coverage")
def coverage(measure: Measure, result: ConditionResult, reference: str, seed: int) -> float:
    table = result.extras.get("calibration", {}).get(measure.predictor)
    if table is None:
        raise MopError(
            f"coverage of {measure.predictor!r} needs the 'calibration' analysis on a Gaussian predictor"
        )
    return float(np.interp(measure.level, table["levels"], table["coverage"]))


@MEASURES.register("matrix_power_max")
def matrix_power_max(measure: Measure, result: ConditionResult, reference: str, seed: int) -> float:
    if "matrix_power_ratio" not in result.extras:
        raise MopError("matrix_power_max needs the 'matrix_powers' analysis")
    return float(max(result.extras["matrix_power_ratio"]))


def sweep(results: Results, axis: str) -> list:
    """The condition results placed on sweep axis `axis`, in the experiment's order."""
    points = [r for r in results.values() if r.condition.x and r.condition.x[0] == axis]
    if not points:
        raise MopError(f"no condition lies on the sweep axis {axis!r}")
    return points


def slope_fit(results: Results, axis: str) -> dict:
    """Log-log OLS fit of the excess MSE against the axis value, with a Student-t 95% interval (n - 2 dof)."""
    from scipy.stats.distributions import t as student_t  # imported here, not at `mop` start-up

    points = sweep(results, axis)
    values = [r.condition.x[1] for r in points]
    excess = [r.extras["excess_mse"] for r in points]
    slope, intercept, se = loglog_slope(values, excess)
    half = float(student_t.ppf(0.975, max(len(values) - 2, 1))) * se
    return {
        "values": values,
        "excess_mse": excess,
        "slope": slope,
        "intercept": intercept,
        "slope_stderr": se,
        "slope_ci95": [slope - half, slope + half],
    }


def measure_value(
    measure: Measure, results: Results, reference: str, seed: int
) -> float | tuple[float, float]:
    """Evaluate `measure` on the results (one condition, or every one reduced by max/min)."""
    if measure.metric == "slope":
        fit = slope_fit(results, measure.axis)
        return tuple(fit["slope_ci95"]) if len(fit["values"]) > 2 else (float("nan"), float("nan"))
    fn = MEASURES.get(measure.metric)
    if measure.condition == "*":
        values = [fn(measure, r, reference, seed) for r in results.values() if measure.predictor in r.errors]
        return max(values) if measure.reduce == "max" else min(values)
    name = measure.condition or next(iter(results))
    if name not in results:
        raise MopError(f"measure {measure.metric}: no condition {name!r} (have {', '.join(results)})")
    return fn(measure, results[name], reference, seed)


def describe(measure: Measure, reference: str) -> str:
    """A short human name of the measure for the report."""
    where = f" [{measure.condition}]" if measure.condition else ""
    start, stop = measure.window
    window = f"t in [{start},{'T' if stop is None else stop})"
    if measure.metric == "mse_ratio":
        bound = "" if measure.bound == "ratio" else f" (CI {measure.bound})"
        return f"MSE {measure.predictor}/{measure.reference or reference} over {window}{bound}{where}"
    if measure.metric == "mean_error":
        return f"mean error of {measure.predictor} over {window}{where}"
    if measure.metric == "coverage":
        return f"{int(measure.level * 100)}% coverage of {measure.predictor}{where}"
    if measure.metric == "slope":
        return f"log-log slope against {measure.axis} (95% CI)"
    return f"{measure.metric}{where}"
