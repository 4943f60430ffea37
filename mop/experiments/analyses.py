"""Analyses: extra per-condition results an experiment asks for by name, each a registered function.

    extras = ANALYSES.get("calibration")(result, predictors)   # merged into the condition's eval.json entry

An analysis sees the condition's test trajectories, its predictors and their errors; it returns a dict.
"""

from __future__ import annotations

import numpy as np

from mop.errors import MopError
from mop.evaluate import windows
from mop.experiments.results import ConditionResult
from mop.filters.kalman import expected_norm, optimal_covariances
from mop.metrics import coverage, gaussian_nll, matrix_power_ratio, window_mean
from mop.predictors import Predictor, first_learned, forecast, simulate
from mop.registry import Registry

ANALYSES: Registry = Registry("analysis")
COVERAGE_LEVELS = [round(q, 2) for q in np.arange(0.05, 1.0, 0.05)]


@ANALYSES.register("calibration")
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


@ANALYSES.register("matrix_powers")
def matrix_powers(result: ConditionResult, predictors: list[Predictor], reference: str) -> dict:
    """Fig. 4b: mean over test systems of ||A^k|| / rho(A)^k, k = 0..49 (families with a matrix A)."""
    return {"matrix_power_ratio": matrix_power_ratio(result.traj.params["A"], 50).tolist()}


@ANALYSES.register("excess_mse")
def excess_mse(result: ConditionResult, predictors: list[Predictor], reference: str) -> dict:
    """MSE of the learned model (the first learned predictor) minus the reference's over t in [1, T]
    (floored at 1e-12 for log-log fits)."""
    mse = {name: float((e[:, 1:] ** 2).mean()) for name, e in result.errors.items()}
    return {"excess_mse": max(mse[first_learned(result.errors)] - mse[reference], 1e-12)}


@ANALYSES.register("floor")
def floor(result: ConditionResult, predictors: list[Predictor], reference: str) -> dict:
    """The irreducible error of a linear-Gaussian family: mean over test systems of trace(S_t), the optimal
    filter's E||y_t - yhat_t||^2 at each t (mop.filters.kalman.optimal_covariances), its mean error
    E||e_t|| for e_t ~ N(0, S_t) (Monte Carlo, the error panel's metric), and every predictor's excess MSE
    over the floor in the report's windows (what no predictor can remove is subtracted)."""
    p = result.traj.params
    S = optimal_covariances(p["A"], p["C"], p["Q"], p["R"], result.traj.horizon, p.get("P0"))
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


@ANALYSES.register("forecast")
def forecast_analysis(result: ConditionResult, predictors: list[Predictor], reference: str) -> dict:
    """k-step forecast error against k = 1..FORECAST_STEPS (10) per predictor with a forecast: mean over test
    systems and forecast origins t >= FORECAST_START (20) of ||y_{t+k-1} - forecast_{t,k-1}|| (horizon_errors;
    k = 1 is the one-step error over t >= 20). Predictors without a forecast are left out."""
    steps = min(FORECAST_STEPS, result.traj.horizon + 1 - FORECAST_START)
    start = FORECAST_START if steps >= 1 else 1
    steps = max(steps, 1)
    table = {}
    for p in predictors:
        if not callable(getattr(p, "forecast", None)):
            continue
        table[p.name] = horizon_errors(result.traj.y, forecast(p, result.traj, steps), start)
    return {"forecast": {"k": list(range(1, steps + 1)), "start": start, "error": table}}


def simulation_context(result) -> int:
    """The condition's context c, default 4/5 of the horizon (at least 1)."""
    T = result.traj.horizon
    c = result.condition.context
    return min(max(1, (4 * T) // 5 if c is None else c), T)


@ANALYSES.register("simulation")
def simulation_analysis(result, predictors: list, reference: str) -> dict:
    """Free-run simulation after the condition's context c (simulation_context), for every predictor with a
    forecast or a simulate: each system's RMSE over y_c..y_T and the outputs, averaged over systems
    (Forgione et al.'s convention), and beside it the one-step RMSE over the same steps.
    Predictors that can do neither are left out."""
    c = simulation_context(result)
    y = result.traj.y[:, c:].double()
    m = y.shape[-1]
    table = {}
    for p in predictors:
        if not (callable(getattr(p, "simulate", None)) or callable(getattr(p, "forecast", None))):
            continue
        sim = simulate(p, result.traj, c).double()
        one = result.errors[p.name][:, c:]  # (N, T+1-c) ||e_t||
        table[p.name] = {
            "simulation_rmse": float(((sim - y) ** 2).mean((1, 2)).sqrt().mean()),
            "one_step_rmse": float(np.sqrt((one**2).mean(1) / m).mean()),
        }
    return {"simulation": {"context": c, "rmse": table}}
