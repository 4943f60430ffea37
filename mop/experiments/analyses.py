"""Analyses: extra per-condition results an experiment asks for by name, each a registered function.

    extras = ANALYSES.get("calibration")(result, predictors)   # merged into the condition's eval.json entry

An analysis sees the condition's test trajectories, its predictors and their errors; it returns a dict.
"""

from __future__ import annotations

import numpy as np

from mop.errors import MopError
from mop.metrics import coverage, gaussian_nll, matrix_power_ratio
from mop.registry import Registry

ANALYSES: Registry = Registry("analysis")
COVERAGE_LEVELS = [round(q, 2) for q in np.arange(0.05, 1.0, 0.05)]


@ANALYSES.register("calibration")
def calibration(result, predictors: list, reference: str) -> dict:
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
def matrix_powers(result, predictors: list, reference: str) -> dict:
    """Fig. 4b: mean over test systems of ||A^k|| / rho(A)^k, k = 0..49 (families with a matrix A)."""
    return {"matrix_power_ratio": matrix_power_ratio(result.traj.params["A"], 50).tolist()}


@ANALYSES.register("excess_mse")
def excess_mse(result, predictors: list, reference: str) -> dict:
    """MSE of MOP minus the reference's over t in [1, T] (floored at 1e-12 for log-log fits)."""
    mse = {name: float((e[:, 1:] ** 2).mean()) for name, e in result.errors.items()}
    return {"excess_mse": max(mse["mop"] - mse[reference], 1e-12)}


@ANALYSES.register("floor")
def floor(result, predictors: list, reference: str) -> dict:
    """The irreducible error of a linear-Gaussian family: mean over test systems of trace(S_t), the optimal
    filter's E||y_t - yhat_t||^2 at each t (mop.filters.kalman.optimal_mse_curve), and every predictor's
    excess MSE over it in the report's windows (what no predictor can remove is subtracted)."""
    from mop.evaluate import windows
    from mop.filters.kalman import optimal_mse_curve
    from mop.metrics import window_mean

    p = result.traj.params
    curve = optimal_mse_curve(p["A"], p["C"], p["Q"], p["R"], result.traj.horizon, p.get("P0")).mean(0)
    curve = curve.tolist()  # (T+1,)
    excess = {
        name: {
            w: window_mean(c["squared_error"], *span) - window_mean(curve, *span)
            for w, span in windows(result.traj.horizon).items()
        }
        for name, c in result.summary["predictors"].items()
    }
    return {"floor": {"mse": curve, "excess_mse": excess}}
