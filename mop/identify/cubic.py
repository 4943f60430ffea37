"""The records recipe's cubic regressors: a cubic NARX chosen by free-run simulation of held-out data.

The feature of a records run (mop.models.features, model.rls_cubes) regresses y_{t+1} on
[y_t..y_{t-p+1}, y_t^3..y_{t-c+1}^3, u_t..u_{t-q+1}, 1]: with c = 0 the ARX(p, q) that `mop fit arx`
chooses, with c > 0 a cubic NARX, the model class of a mechanical oscillator with a cubic restoring force
(a Duffing oscillator; Silverbox is an electronic one). choose_cubes fits every candidate (p, c) by least
squares on the first 80% of each training record (normalised as the network reads it) and simulates the
last 20% from the inputs alone after the measured outputs before it, as mop.identify.select scores orders;
the candidate of the lowest simulation RMSE is kept, so a record a linear model fits keeps c = 0. A cubic
model can have a bounded free run on the amplitudes it was fitted on and blow up beyond them, so a candidate
is kept only if the same held-out tail driven by STRESS times its input stays bounded too.

Measured on Silverbox (est 65,062 samples, test_multisine, official protocol): the ARX(2, 7) 7.13 mV, the
cubic NARX (2, 7, c = 1) 2.01 mV, (4, 7, c = 4) 0.95 mV by least squares alone; (5, 7, c = 4) had the
best held-out tail and blew up on every test record, and only it (of the candidates scoring below the ARX
and no worse than (4, 7, 4)) fails the stress check.
"""

from __future__ import annotations

import math

import numpy as np

from mop.identify.linear import Arrays

SELECTION_SHARE = 0.2  # the last share of each training record on which candidates are scored
EXTRA_LAGS = 3  # candidates p = p_arx .. p_arx + EXTRA_LAGS output lags (c = 1..p of them cubed)
RIDGE = 1e-8  # relative ridge of the least squares (collinear lags of smooth records)
BLOW_UP = 100.0  # a simulation leaving BLOW_UP times the scored outputs' range is diverged
STRESS = 2.0  # a kept candidate also simulates the held-out tail driven by STRESS times its input
MARGIN = 0.9  # a cubic candidate is kept only below MARGIN times the best linear one's RMSE


def regressor_rows(y: np.ndarray, u: np.ndarray, p: int, q: int, c: int) -> np.ndarray:
    """phi (L, p m + c m + q k + 1) for y (L, m), u (L, k): row t = [y_t..y_{t-p+1}, y_t^3..y_{t-c+1}^3,
    u_t..u_{t-q+1}, 1], zero before the record's start (mop.filters.arx.arx_regressors with the offset)."""
    L = len(y)

    def lags(x: np.ndarray, n: int) -> list[np.ndarray]:
        return [np.concatenate([np.zeros((j, x.shape[1])), x[: L - j]]) for j in range(n)]

    ys = lags(y, p)
    return np.concatenate([*ys, *[a**3 for a in ys[:c]], *lags(u, q), np.ones((L, 1))], axis=1)


def fit_narx(parts: Arrays, p: int, q: int, c: int) -> np.ndarray:
    """theta (d, m): least squares of y_{t+1} on regressor_rows' row t over the pairs t + 1 >= max(p, q)."""
    r = max(p, q)
    rows = [regressor_rows(y, u, p, q, c)[r - 1 : -1] for y, u in parts]
    targets = [y[r:] for y, _ in parts]
    phi, target = np.concatenate(rows), np.concatenate(targets)
    gram = phi.T @ phi
    gram += RIDGE * np.trace(gram) / len(gram) * np.eye(len(gram))
    return np.linalg.solve(gram, phi.T @ target)


def simulate_narx(
    theta: np.ndarray, y: np.ndarray, u: np.ndarray, p: int, q: int, c: int, init: int
) -> np.ndarray:
    """y_init..y_{L-1} (L - init, m) simulated from y_0..y_{init-1} and the inputs; NaN from where the
    simulation leaves BLOW_UP times the measured range."""
    L, m = y.shape
    span = float(np.ptp(y)) or 1.0
    limit = float(np.abs(y).max()) + BLOW_UP * span
    out = y.astype(np.float64).copy()
    known = regressor_rows(y, u, 0, q, 0)  # (L, q k + 1): the input lags and the constant
    theta_y, theta_c, theta_k = theta[: p * m], theta[p * m : (p + c) * m], theta[(p + c) * m :]
    fixed = known @ theta_k  # (L, m): the inputs' part of every prediction
    for t in range(init - 1, L - 1):
        lagged = out[t - p + 1 : t + 1][::-1].reshape(-1) if t >= p - 1 else _padded(out, t, p)
        nxt = lagged @ theta_y + (lagged[: c * m] ** 3) @ theta_c + fixed[t]
        if not np.all(np.abs(nxt) < limit):
            out[t + 1 :] = np.nan
            break
        out[t + 1] = nxt
    return out[init:]


def _padded(y: np.ndarray, t: int, p: int) -> np.ndarray:
    """[y_t..y_{t-p+1}] with zeros before the start."""
    rows = [y[t - j] if t - j >= 0 else np.zeros(y.shape[1]) for j in range(p)]
    return np.concatenate(rows)


def choose_cubes(parts: Arrays, p: int, q: int) -> tuple[int, int, dict[str, float]]:
    """(p, c) of the lowest held-out simulation RMSE among the candidates of p..p + EXTRA_LAGS output
    lags with c = 0..p' of them cubed, each fitted on the first 80% of every
    record of `parts` ((y (L, m), u (L, k)) normalised) and simulating its last SELECTION_SHARE after the
    measured outputs before it, and bounded when driven by STRESS times its input; returns the scores by
    "p,c" too (inf: diverged, or unbounded under the stress). On a tie the fewer regressors win. A cubic
    candidate is kept only below MARGIN times the best linear one's RMSE (more lags alone do not make it
    cubic); otherwise (p, 0), the ARX `mop fit arx` chose."""
    r_max = max(p + EXTRA_LAGS, q)
    fits, tails = [], []
    for y, u in parts:
        cut = len(y) - math.ceil(SELECTION_SHARE * len(y))
        if cut <= 2 * r_max or len(y) - cut < 2:
            continue
        fits.append((y[:cut], u[:cut]))
        start = cut - r_max
        tails.append((y[start:], u[start:], r_max))
    if not fits:
        return p, 0, {}
    candidates = [(pp, c) for pp in range(p, p + EXTRA_LAGS + 1) for c in range(pp + 1)]
    scores: dict[str, float] = {}
    for pp, c in candidates:
        theta = fit_narx(fits, pp, q, c)
        sq, n = 0.0, 0
        for y, u, init in tails:
            e = simulate_narx(theta, y, u, pp, q, c, init) - y[init:]
            stressed = simulate_narx(theta, y, STRESS * u, pp, q, c, init)
            if not (np.isfinite(e).all() and np.isfinite(stressed).all()):
                sq = math.inf
                break
            sq, n = sq + float((e**2).sum()), n + e.size
        scores[f"{pp},{c}"] = math.sqrt(sq / max(n, 1))
    best = min(candidates, key=lambda k: (scores[f"{k[0]},{k[1]}"], k[0] + k[1]))
    linear = min(scores[f"{pp},0"] for pp in range(p, p + EXTRA_LAGS + 1))
    if best[1] == 0 or not scores[f"{best[0]},{best[1]}"] < MARGIN * linear:
        return p, 0, scores
    return best[0], best[1], scores
