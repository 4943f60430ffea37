"""Fitted ARX(p, q) ("arx"): least squares once over every trajectory of an estimation record, then fixed.

Outputs y_t in R^m, inputs u_t in R^k (u_t acts between y_t and y_{t+1}), orders p >= 1 and q >= 1 (q = 0
without inputs). Each output is regressed on all outputs at p lags, all inputs at q lags and a constant:

    y_t = a_1 y_{t-1} + ... + a_p y_{t-p} + b_1 u_{t-1} + ... + b_q u_{t-q} + c + e_t,

one equation for each t = r..T_i of every trajectory i (r = max(p, q)), solved jointly by numpy's lstsq
(theta (p m + q k + 1, m), the minimum-norm solution where the regressors are collinear).

As a mop.identify.linear.LinearModel the state is the lags, x_t = [y_{t-1}..y_{t-p}, u_{t-1}..u_{t-q}]
(n = p m + q k): C = [a_1 .. a_p, b_1 .. b_q] (m, n), d = c, A shifts the lags and writes the prediction
into the newest output lag, B writes u_t into the newest input lag, K = [I_m; 0] (one-step prediction puts
the measured y_t there instead). yhat_0 has its lags at the estimation means (x0); from t = 1 the lags
before the record's start are its first values y_0, u_0 (FittedPredictor.states).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from mop.errors import MopError
from mop.identify.linear import IDENTIFIERS, Arrays, FittedPredictor, LinearModel


def arx_rows(y: np.ndarray, u: np.ndarray, p: int, q: int) -> tuple[np.ndarray, np.ndarray]:
    """(Phi (N, p m + q k + 1), Y (N, m)) of one trajectory: row t - r is [y_{t-1}..y_{t-p}, u_{t-1}..u_{t-q},
    1] and y_t, for t = r..T (r = max(p, q)); N = 0 when the trajectory is not longer than r."""
    r, T1 = max(p, q), len(y)
    lags = [y[r - j : T1 - j] for j in range(1, p + 1)] + [u[r - j : T1 - j] for j in range(1, q + 1)]
    Phi = np.concatenate([*lags, np.ones((max(T1 - r, 0), 1))], axis=1)
    return Phi, y[r:]


def num_equations(data: Arrays, p: int, q: int) -> int:
    return sum(max(len(y) - max(p, q), 0) for y, _ in data)


def fit_theta(data: Arrays, p: int, q: int) -> np.ndarray:
    """theta (p m + q k + 1, m) minimizing sum over trajectories and t of ||y_t - theta^T phi_t||^2."""
    rows = [arx_rows(y, u, p, q) for y, u in data]
    Phi, Y = np.concatenate([r[0] for r in rows]), np.concatenate([r[1] for r in rows])
    if len(Phi) < Phi.shape[1]:
        raise MopError(
            f"arx: {len(Phi)} equations cannot fit ARX({p}, {q})'s {Phi.shape[1]} coefficients per output; "
            "use a longer record or a lower --max-order"
        )
    return np.linalg.lstsq(Phi, Y, rcond=None)[0]


def arx_model(theta: np.ndarray, p: int, q: int, y_mean: np.ndarray, u_mean: np.ndarray) -> LinearModel:
    """The lag-state LinearModel of ARX(p, q) with coefficients theta (p m + q k + 1, m)."""
    m, k = len(y_mean), len(u_mean)
    py, n = p * m, p * m + q * k
    C, d = theta[:n].T.copy(), theta[n].copy()
    A, B = np.zeros((n, n)), np.zeros((n, k))
    A[:m] = C  # the newest output lag becomes the prediction (simulation) ...
    A[m:py, : py - m] = np.eye(py - m)  # ... the older output lags shift down
    if q:
        B[py : py + k] = np.eye(k)  # u_t becomes the newest input lag
        A[py + k :, py : n - k] = np.eye(n - py - k)
    K = np.zeros((n, m))
    K[:m] = np.eye(m)  # ... or, one step ahead, the measured y_t
    b = np.concatenate([d, np.zeros(n - m)])
    x0 = np.concatenate([np.tile(y_mean, p), np.tile(u_mean, q)])
    return LinearModel(A=A, B=B, C=C, K=K, b=b, d=d, x0=x0)


def means(data: Arrays) -> tuple[np.ndarray, np.ndarray]:
    """(y mean (m,), u mean (k,)) over every sample of the record."""
    return np.concatenate([y for y, _ in data]).mean(0), np.concatenate([u for _, u in data]).mean(0)


class ARX:
    """The "arx" identifier: grid p = 1..P, q = 1..P (q = 0 without inputs)."""

    kind = "arx"
    lag_state = True

    @staticmethod
    def candidates(max_order: int, input_dim: int) -> list[dict[str, int]]:
        qs = range(1, max_order + 1) if input_dim else [0]
        return [{"p": p, "q": q} for p in range(1, max_order + 1) for q in qs]

    @staticmethod
    def size(orders: dict[str, int], output_dim: int, input_dim: int) -> int:
        """Coefficients per output (without the intercept): p m + q k."""
        return orders["p"] * output_dim + orders["q"] * input_dim

    @staticmethod
    def feasible(data: Arrays, orders: dict[str, int], max_order: int) -> bool:
        """Whether the record has at least as many equations as ARX(p, q) has coefficients per output."""
        p, q = orders["p"], orders["q"]
        y, u = data[0]
        return num_equations(data, p, q) >= p * y.shape[1] + q * u.shape[1] + 1

    @staticmethod
    def fit_grid(
        data: Arrays, candidates: list[dict[str, int]], info: dict[str, Any], max_order: int
    ) -> list[FittedPredictor]:
        y_mean, u_mean = means(data)
        m, k = len(y_mean), len(u_mean)
        out = []
        for orders in candidates:
            theta = fit_theta(data, orders["p"], orders["q"])
            model = arx_model(theta, orders["p"], orders["q"], y_mean, u_mean)
            out.append(FittedPredictor(ARX.kind, dict(orders), model, m, k, dict(info), lag_state=True))
        return out


IDENTIFIERS.add(ARX.kind, ARX)
