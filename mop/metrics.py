"""Error curves, window means, MSE ratios with bootstrap confidence intervals, and calibration metrics.

Shapes: per-system errors e (N, T+1) with e[i, t] = ||yhat_t - y_t||_2 for test system i.

Missing outputs (NaN in y): e[i, t] is the norm over the measured channels only, NaN where none was
measured; every summary then averages over the measured (non-NaN) entries. Without gaps the plain formulas
run unchanged.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import torch
from torch import Tensor


def errors(yhat: Tensor, y: Tensor) -> np.ndarray:
    """e[i, t] = ||yhat[i, t] - y[i, t]||_2, (N, T+1, m) -> (N, T+1) float64; with NaN in y (missing
    outputs) the norm over the measured channels, NaN at steps with none measured."""
    diff = yhat.double() - y.double()
    seen = ~torch.isnan(y)
    if bool(seen.all()):
        return torch.linalg.vector_norm(diff, dim=-1).cpu().numpy()
    e = torch.linalg.vector_norm(torch.where(seen, diff, 0), dim=-1)
    return torch.where(seen.any(-1), e, float("nan")).cpu().numpy()


def error_curves(e: np.ndarray) -> dict[str, list[float]]:
    """Mean over systems of e_t, of e_t^2, and the std of e_t over systems: each a list of length T+1
    (over the systems measured at t where e holds NaN)."""
    if np.isnan(e).any():
        with warnings.catch_warnings():  # a step no system measured gives NaN ("mean of empty slice")
            warnings.simplefilter("ignore", RuntimeWarning)
            mean, sq, std = np.nanmean(e, 0), np.nanmean(e**2, 0), np.nanstd(e, 0)
        return {"error": mean.tolist(), "squared_error": sq.tolist(), "std": std.tolist()}
    return {"error": e.mean(0).tolist(), "squared_error": (e**2).mean(0).tolist(), "std": e.std(0).tolist()}


def window_mean(curve: np.ndarray | list[float], start: int, stop: int) -> float:
    """Mean of curve[t] over t in [start, stop) (stop clipped to the curve's length)."""
    curve = np.asarray(curve, dtype=float)
    part = curve[start : min(stop, len(curve))]
    return float(np.nanmean(part) if np.isnan(part).any() else part.mean())


def mse_ratio_ci(
    e_num: np.ndarray,
    e_den: np.ndarray,
    start: int,
    stop: int,
    *,
    num_boot: int = 2000,
    level: float = 0.95,
    seed: int = 0,
) -> tuple[float, float, float]:
    """Ratio of mean squared errors over t in [start, stop), and a percentile bootstrap CI over systems.

    ratio = sum_i s_num_i / sum_i s_den_i with s_i = sum_{t in window} e[i, t]^2; the CI resamples
    systems i with replacement (paired: both predictors see the same resampled systems), seeded.
    """
    s_num = (e_num[:, start:stop] ** 2).sum(1)  # (N,)
    s_den = (e_den[:, start:stop] ** 2).sum(1)  # (N,)
    if np.isnan(s_num).any() or np.isnan(s_den).any():  # missing outputs: both over the measured steps
        both = ~(np.isnan(e_num[:, start:stop]) | np.isnan(e_den[:, start:stop]))
        s_num = (np.where(both, e_num[:, start:stop], 0.0) ** 2).sum(1)
        s_den = (np.where(both, e_den[:, start:stop], 0.0) ** 2).sum(1)
    rng = np.random.default_rng(seed)
    index = rng.integers(0, len(s_num), size=(num_boot, len(s_num)))  # (num_boot, N)
    boot = s_num[index].sum(1) / s_den[index].sum(1)
    alpha = (1 - level) / 2
    low, high = np.quantile(boot, [alpha, 1 - alpha])
    return float(s_num.sum() / s_den.sum()), float(low), float(high)


def gaussian_nll(y: Tensor, mean: Tensor, var: Tensor) -> float:
    """Mean over systems, times and outputs of -log N(y; mean, var) (diagonal variance)."""
    y, mean, var = y.double(), mean.double(), var.double()
    return float((0.5 * (torch.log(2 * math.pi * var) + (y - mean) ** 2 / var)).mean())


def coverage(y: Tensor, mean: Tensor, var: Tensor, level: float) -> float:
    """Fraction of scalar outputs inside the central `level` interval mean +- z sqrt(var) of N(mean, var)."""
    z = math.sqrt(2) * torch.special.erfinv(torch.tensor(level, dtype=torch.float64))
    inside = (y.double() - mean.double()).abs() <= z * var.double().sqrt()
    return float(inside.double().mean())


def loglog_slope(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """OLS slope of log y on log x and its standard error: (slope, intercept, stderr)."""
    lx, ly = np.log(np.asarray(x, float)), np.log(np.asarray(y, float))
    X = np.stack([lx, np.ones_like(lx)], 1)
    coef, *_ = np.linalg.lstsq(X, ly, rcond=None)
    dof = max(len(lx) - 2, 1)
    sigma2 = float(((ly - X @ coef) ** 2).sum() / dof)
    stderr = math.sqrt(sigma2 * np.linalg.inv(X.T @ X)[0, 0])
    return float(coef[0]), float(coef[1]), stderr


def matrix_power_ratio(A: Tensor, num_powers: int) -> np.ndarray:
    """Average over systems of ||A^k||_2 / rho(A)^k for k = 0..num_powers-1 (Fig. 4b); A (B, n, n)."""
    A = A.double()
    rho = torch.linalg.eigvals(A).abs().amax(-1)  # (B,)
    P = torch.eye(A.shape[-1], dtype=A.dtype).expand_as(A)
    out = []
    for k in range(num_powers):
        out.append(float((torch.linalg.matrix_norm(P, ord=2) / rho**k).mean()))
        P = P @ A
    return np.array(out)
