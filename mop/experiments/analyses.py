"""Analyses: extra per-condition results an experiment asks for by name, each a registered function.

    extras = ANALYSES.get("calibration")(result, predictors, reference)  # into the condition's eval.json

An analysis sees a condition's trajectories, predictors and errors, returns a dict, and renders itself:
    markdown(extras) -> str        its section of the condition in report.md ("" for none)
    to_json(results) -> dict       entries it adds to eval.json over all conditions (e.g. "sweeps")
    sections(entries) -> list[str] report.md sections of those entries
Measures reading these extras (coverage, matrix_power_max, slope) are registered here; figures use accessors.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from mop.errors import MopError
from mop.evaluate import windows
from mop.experiments.measures import MEASURES, where
from mop.experiments.results import ConditionResult, Results
from mop.experiments.spec import Measure
from mop.filters.kalman import expected_norm, optimal_covariances
from mop.metrics import coverage, gaussian_nll, loglog_slope, matrix_power_ratio, window_mean
from mop.predictors import Predictor, first_learned, forecast, simulate
from mop.registry import Registry
from mop.report import forecast_markdown, rmse_cell, simulation_cell
from mop.systems.base import require_params

ANALYSES: Registry = Registry(
    "analysis",
    keys={
        "markdown": "extras -> the report's table",
        "to_json": "results -> entries for eval.json",
        "sections": "entries -> report sections",
        "forecast_steps": "horizon -> the forecast steps it needs (validation)",
    },
)
COVERAGE_LEVELS = [round(q, 2) for q in np.arange(0.05, 1.0, 0.05)]


def _calibration_table(extras: dict) -> str:
    lines = ["| predictor | NLL | coverage 50% | 90% | 95% |", "|---|---|---|---|---|"]
    lines += [
        f"| {n} | {r['nll']:.4f} | {r['coverage_50']:.3f} | {r['coverage_90']:.3f} | {r['coverage_95']:.3f} |"
        for n, r in extras["calibration"].items()
    ]
    return "\n".join(lines) + "\n"


@ANALYSES.register("calibration", markdown=_calibration_table)
def calibration(result: ConditionResult, predictors: list[Predictor], reference: str) -> dict:
    """Coverage of central intervals and Gaussian NLL over t >= 1, for every predictor with a distribution."""
    y = result.traj.y[:, 1:]
    table = {}
    for p in predictors:
        if not callable(getattr(p, "predict_distribution", None)):
            continue
        try:
            mean, var = p.predict_distribution(result.traj)  # (N, T+1, m) each
        except MopError:  # e.g. a learned model with a mean-only read-out
            continue
        mean, var = mean[:, 1:], var[:, 1:]
        table[p.name] = {
            "nll": gaussian_nll(y, mean, var),
            **{f"coverage_{int(q * 100)}": coverage(y, mean, var, q) for q in (0.5, 0.9, 0.95)},
            "levels": COVERAGE_LEVELS,
            "coverage": [coverage(y, mean, var, q) for q in COVERAGE_LEVELS],
        }
    return {"calibration": table}


def calibration_table(result: ConditionResult) -> dict:
    """predictor -> {"nll", "coverage_50", ..., "levels", "coverage"} of the calibration analysis ({}
    where it did not run)."""
    return result.extras.get("calibration", {})


def _coverage_text(measure: Measure, reference: str) -> str:
    return f"{int(measure.level * 100)}% coverage of {measure.predictor}{where(measure)}"


@MEASURES.register("coverage", describe=_coverage_text, needs="calibration")
def coverage_measure(measure: Measure, result: ConditionResult, reference: str, seed: int) -> float:
    """Empirical coverage of the central `level` interval of `predictor` (interpolated between levels)."""
    table = calibration_table(result).get(measure.predictor)
    if table is None:
        raise MopError(
            f"coverage of {measure.predictor!r} needs the 'calibration' analysis on a Gaussian predictor"
        )
    return float(np.interp(measure.level, table["levels"], table["coverage"]))


@ANALYSES.register("matrix_powers")
def matrix_powers(result: ConditionResult, predictors: list[Predictor], reference: str) -> dict:
    """Fig. 4b: mean over test systems of ||A^k|| / rho(A)^k, k = 0..49 (families with a matrix A)."""
    require_params(result.traj.params, ("A",), by="the matrix_powers analysis")
    return {"matrix_power_ratio": matrix_power_ratio(result.traj.params.A, 50).tolist()}


def power_ratio(result: ConditionResult) -> list[float] | None:
    """The matrix_powers analysis's mean ||A^k|| / rho(A)^k, k = 0..49, or None where it did not run."""
    return result.extras.get("matrix_power_ratio")


@MEASURES.register("matrix_power_max", needs="matrix_powers")
def matrix_power_max(measure: Measure, result: ConditionResult, reference: str, seed: int) -> float:
    """max over k of the mean ||A^k|| / rho(A)^k of the condition's test systems."""
    ratio = power_ratio(result)
    if ratio is None:
        raise MopError("matrix_power_max needs the 'matrix_powers' analysis")
    return float(max(ratio))


def sweep(results: Results, axis: str) -> list[ConditionResult]:
    """The condition results placed on sweep axis `axis`, in the experiment's order."""
    points = [r for r in results.values() if r.condition.x and r.condition.x[0] == axis]
    if not points:
        raise MopError(f"no condition lies on the sweep axis {axis!r}")
    return points


def sweep_axes(results: Results) -> list[str]:
    """The sweep axes of the conditions, in order of first appearance."""
    return list(dict.fromkeys(r.condition.x[0] for r in results.values() if r.condition.x))


def slope_fit(results: Results, axis: str) -> dict:
    """Log-log OLS fit of the excess MSE against the axis value, with a Student-t 95% interval (n - 2 dof)."""
    from scipy.stats.distributions import t as student_t  # imported here, not at `mop` start-up

    points = sweep(results, axis)
    values = [r.condition.x[1] for r in points]
    excess = [r.extras["excess_mse"] for r in points]
    slope, intercept, se = loglog_slope(values, excess)
    half = float(student_t.ppf(0.975, max(len(values) - 2, 1))) * se
    fit = {"values": values, "excess_mse": excess, "slope": slope, "intercept": intercept}
    return fit | {"slope_stderr": se, "slope_ci95": [slope - half, slope + half]}


def _sweeps(results: Results) -> dict:
    sweeps = {axis: slope_fit(results, axis) for axis in sweep_axes(results)}
    return {"sweeps": sweeps} if sweeps else {}


def _sweep_sections(entries: dict) -> list[str]:
    return [_sweep_section(axis, fit) for axis, fit in entries.get("sweeps", {}).items()]


def _sweep_section(axis: str, fit: dict) -> str:
    rows = "\n".join(f"| {v:g} | {e:.5f} |" for v, e in zip(fit["values"], fit["excess_mse"], strict=True))
    low, high = fit["slope_ci95"]
    return (
        f"## against {axis}\n\nExcess MSE = test MSE of MOP minus the reference's, over t in [1,T]; "
        f"the theorem's bound predicts a slope of -1/2.\n\n| {axis} | excess MSE |\n|---|---|\n{rows}\n\n"
        f"slope {fit['slope']:.3f} (OLS s.e. {fit['slope_stderr']:.3f}, "
        f"95% t-interval [{low:.3f}, {high:.3f}], "
        f"{len(fit['values']) - 2} dof)\n"
    )


@ANALYSES.register("excess_mse", to_json=_sweeps, sections=_sweep_sections)
def excess_mse(result: ConditionResult, predictors: list[Predictor], reference: str) -> dict:
    """MSE of the learned model (the first learned predictor) minus the reference's over t in [1, T]
    (floored at 1e-12 for log-log fits); over all conditions, eval.json's "sweeps": the log-log fit
    against each sweep axis (slope_fit)."""
    mse = {name: float((e[:, 1:] ** 2).mean()) for name, e in result.errors.items()}
    return {"excess_mse": max(mse[first_learned(result.errors)] - mse[reference], 1e-12)}


def _slope_text(measure: Measure, reference: str) -> str:
    return f"log-log slope against {measure.axis} (95% CI)"


@MEASURES.register("slope", over_conditions=True, interval=True, describe=_slope_text, needs="excess_mse")
def slope(measure: Measure, results: Results, reference: str, seed: int) -> tuple[float, float]:
    """95% interval of the log-log slope of the excess MSE over the conditions of sweep axis `axis`
    (NaN for fewer than 3 points)."""
    fit = slope_fit(results, measure.axis)
    return tuple(fit["slope_ci95"]) if len(fit["values"]) > 2 else (float("nan"), float("nan"))


def _floor_table(extras: dict) -> str:
    excess = extras["floor"]["excess_mse"]
    wins = list(next(iter(excess.values())))
    head = "Excess MSE over the irreducible error (mean trace S_t of the optimal filter of each test system):"
    cols = "".join(f" t in {w} |" for w in wins)
    lines = [head, "", f"| predictor |{cols}", "|---" * (len(wins) + 1) + "|"]
    lines += [f"| {n} | " + " | ".join(f"{e[w]:+.4f}" for w in wins) + " |" for n, e in excess.items()]
    return "\n".join(lines) + "\n"


@ANALYSES.register("floor", markdown=_floor_table)
def floor(result: ConditionResult, predictors: list[Predictor], reference: str) -> dict:
    """The irreducible error of a linear-Gaussian family: mean over test systems of trace(S_t), the optimal
    filter's E||y_t - yhat_t||^2 at each t (mop.filters.kalman.optimal_covariances), its mean error
    E||e_t|| for e_t ~ N(0, S_t) (Monte Carlo, the error panel's metric), and every predictor's excess MSE
    over the floor in the report's windows (what no predictor can remove is subtracted)."""
    p = result.traj.params
    require_params(p, ("A", "C", "Q", "R", "P0"), by="the floor analysis")
    S = optimal_covariances(p.A, p.C, p.Q, p.R, result.traj.horizon, p.P0)
    # S (N, T+1, m, m)
    curve = S.diagonal(dim1=-2, dim2=-1).sum(-1).mean(0).tolist()  # (T+1,)
    mean_norm = expected_norm(S, num_samples=500).mean(0).tolist()  # (T+1,)
    excess = {
        name: {
            w: window_mean(c["squared_error"], *span) - window_mean(curve, *span)
            for w, span in windows(result.traj.horizon).items()
        }
        for name, c in result.summary["predictors"].items()
    }
    return {"floor": {"mse": curve, "mean_norm": mean_norm, "excess_mse": excess}}


def floor_curve(result: ConditionResult) -> list[float] | None:
    """The floor analysis's irreducible MSE per t (T+1,), or None where it did not run."""
    return result.extras.get("floor", {}).get("mse")


def floor_mean_norm(result: ConditionResult) -> list[float] | None:
    """The floor analysis's irreducible mean error E||e_t|| per t (T+1,), or None where it did not run."""
    return result.extras.get("floor", {}).get("mean_norm")


FORECAST_STEPS = 10
FORECAST_START = 20


def horizon_errors(y, f, start: int = FORECAST_START) -> list[float]:
    """Mean ||y_{t+j} - f[:, t, j]||_2 over systems and origins t >= start (with t + j <= T), j = 0..K-1:
    the k-step error for k = j + 1. y (B, T+1, m), f (B, T+1, K, m) with NaN past T (those are skipped)."""
    T1, K = y.shape[1], f.shape[2]
    out = []
    for j in range(K):
        e = (y[:, start + j :].double() - f[:, start : T1 - j, j].double()).norm(dim=-1)  # (B, T+1-start-j)
        out.append(float(e.mean()) if e.numel() else float("nan"))
    return out


def _forecast_table(extras: dict) -> str:
    return "\n".join(forecast_markdown(extras["forecast"])) + "\n"


def forecast_steps(horizon: int) -> int:
    """The steps K the forecast analysis asks of every predictor on trajectories of `horizon` steps."""
    return max(min(FORECAST_STEPS, horizon + 1 - FORECAST_START), 1)


@ANALYSES.register("forecast", markdown=_forecast_table, forecast_steps=forecast_steps)
def forecast_analysis(result: ConditionResult, predictors: list[Predictor], reference: str) -> dict:
    """k-step forecast error against k = 1..FORECAST_STEPS (10) per predictor with a forecast: mean over test
    systems and forecast origins t >= FORECAST_START (20) of ||y_{t+k-1} - forecast_{t,k-1}|| (horizon_errors;
    k = 1 is the one-step error over t >= 20). Predictors without a forecast are left out."""
    start = FORECAST_START if result.traj.horizon + 1 - FORECAST_START >= 1 else 1
    steps = forecast_steps(result.traj.horizon)
    table = {}
    for p in predictors:
        if not callable(getattr(p, "forecast", None)):
            continue
        table[p.name] = horizon_errors(result.traj.y, forecast(p, result.traj, steps, start), start)
    return {"forecast": {"k": list(range(1, steps + 1)), "start": start, "error": table}}


def forecast_table(result: ConditionResult) -> dict | None:
    """The forecast analysis's {"k", "start", "error": predictor -> errors per k}, or None if not run."""
    return result.extras.get("forecast")


def condition_sections(analyses: tuple[str, ...], extras: dict) -> list[str]:
    """The report sections the analyses `analyses` render from one condition's extras, in their order."""
    texts = [ANALYSES.meta(name).get("markdown", lambda _: "")(extras) for name in analyses]
    return [t for t in texts if t]


def experiment_entries(analyses: tuple[str, ...], results: Results) -> dict:
    """What the analyses add to eval.json over all conditions (e.g. "sweeps"), merged in order."""
    entries: dict = {}
    for name in analyses:
        entries.update(ANALYSES.meta(name).get("to_json", lambda _: {})(results))
    return entries


def experiment_sections(analyses: tuple[str, ...], entries: dict) -> list[str]:
    """The report sections of those entries, in the experiment's order."""
    return [s for name in analyses for s in ANALYSES.meta(name).get("sections", lambda _: [])(entries)]


def simulation_context(result) -> int:
    """The condition's context c, default 4/5 of the horizon (at least 1)."""
    T = result.traj.horizon
    c = result.condition.context
    return min(max(1, (4 * T) // 5 if c is None else c), T)


def _simulation_table(extras: dict) -> str:
    c, rmse = extras["simulation"]["context"], extras["simulation"]["rmse"]
    head = (
        f"Free-run simulation after a context of {c} outputs (y_{c}..y_T from the inputs alone), RMSE over "
        f"those steps beside the one-step RMSE over the same steps and over t >= {RECORD_START} (the whole "
        "record after a start-up, Forgione et al.'s window):\n\n"
        f"| predictor | one-step RMSE | simulation RMSE | one-step RMSE, t >= {RECORD_START} |\n"
        "|---|---|---|---|\n"
    )
    rows = []
    for n, r in rmse.items():
        record = rmse_cell(r.get("one_step_rmse_record"))  # absent from results written before it
        rows.append(f"| {n} | {rmse_cell(r['one_step_rmse'])} | {simulation_cell(r)} | {record} |\n")
    return head + "".join(rows)


SIMULATION = "simulation"  # the analysis (and its extras key), as the card build asks for it
RECORD_START = 50  # the one-step RMSE over the record from this step on (Forgione et al.'s window)


@ANALYSES.register(SIMULATION, markdown=_simulation_table)
def simulation_analysis(result, predictors: list, reference: str) -> dict:
    """Free-run simulation after the condition's context c (simulation_context), for every predictor with a
    forecast or a simulate: each system's RMSE over y_c..y_T and the outputs, averaged over systems
    (Forgione et al.'s convention), and beside it the one-step RMSE over the same steps and over the whole
    record from RECORD_START on (each system's, averaged alike). Predictors that can do neither are left
    out."""
    c = simulation_context(result)
    y = result.traj.y[:, c:].double()
    m = y.shape[-1]
    table = {}
    for p in predictors:
        if not (callable(getattr(p, "simulate", None)) or callable(getattr(p, "forecast", None))):
            continue
        sim = simulate(p, result.traj, c).double()
        per_system = ((sim - y) ** 2).mean((1, 2)).sqrt()  # (N,): NaN or inf where the free run diverged
        diverged = int((~torch.isfinite(per_system)).sum())
        table[p.name] = {
            "simulation_rmse": float(per_system.mean()) if diverged == 0 else math.inf,
            "one_step_rmse": _one_step_from(result.errors[p.name], c, m),
            "one_step_rmse_record": _one_step_from(result.errors[p.name], min(RECORD_START, c), m),
        }
        if diverged:  # the mean over systems is inf, not the mean over those that stayed finite
            table[p.name]["diverged_systems"] = diverged
    return {"simulation": {"context": c, "rmse": table}}


def _one_step_from(errors, start: int, m: int) -> float:
    """Each system's one-step RMSE over t >= start from ||e_t|| (N, T+1) over m outputs, averaged."""
    tail = errors[:, start:]
    return float(np.sqrt((tail**2).mean(1) / m).mean())


def _simulation(result: ConditionResult, name: str) -> dict:
    table = result.extras.get("simulation", {}).get("rmse", {})
    if name not in table:
        raise MopError(f"simulation RMSE of {name!r} needs the 'simulation' analysis and a forecast")
    return table[name]


def _simulation_text(measure: Measure, reference: str) -> str:
    if measure.metric == "one_step_rmse_record":
        return f"one-step RMSE of {measure.predictor} over t >= {RECORD_START}{where(measure)}"
    kind = "simulation" if measure.metric == "simulation_rmse" else "one-step"
    return f"{kind} RMSE of {measure.predictor} after the context{where(measure)}"


@MEASURES.register("simulation_rmse", describe=_simulation_text, needs="simulation")
def simulation_rmse(measure: Measure, result: ConditionResult, reference: str, seed: int) -> float:
    """The simulation analysis's free-run RMSE of `predictor` after the context."""
    return _simulation(result, measure.predictor)["simulation_rmse"]


@MEASURES.register("one_step_rmse", describe=_simulation_text, needs="simulation")
def one_step_rmse(measure: Measure, result: ConditionResult, reference: str, seed: int) -> float:
    """The simulation analysis's one-step RMSE of `predictor` over the same steps."""
    return _simulation(result, measure.predictor)["one_step_rmse"]


@MEASURES.register("one_step_rmse_record", describe=_simulation_text, needs="simulation")
def one_step_rmse_record(measure: Measure, result: ConditionResult, reference: str, seed: int) -> float:
    """The simulation analysis's one-step RMSE of `predictor` over t >= RECORD_START."""
    row = _simulation(result, measure.predictor)
    if "one_step_rmse_record" not in row:
        raise MopError("this result predates the one-step RMSE over the record: evaluate it again")
    return row["one_step_rmse_record"]
