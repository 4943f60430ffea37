"""Fitted N4SID ("n4sid"): subspace identification once over every trajectory of an estimation record.

The algorithm of mop.filters.subspace (identify_with_inputs, and identify without inputs), with the block
Hankel columns of all trajectories side by side, on data with the estimation means removed:

    W_p = [U_p; Y_p],  Y_f = L_w W_p + L_u U_f (least squares),  O = L_w W_p = U S V^T,
    X = S_n^{1/2} V_n^T  (states at times i..T_i - i + 1 of each trajectory),
    [X_+] = [A B] [X_-; U],  Y = C X_-   (least squares over the pairs inside each trajectory),

giving x_{t+1} = A x_t + B (u_t - u_mean) + K e_t, y_t = C x_t + y_mean + e_t (no D: u_t acts between y_t and
y_{t+1}). K is the steady-state Kalman gain of the residual covariances [Q S; S^T R] of [X_+ - A X_- - B U;
Y - C X_-] (the filter DARE, scipy), or the regression W E^T (E E^T)^{-1} where the DARE has no solution.
The SVD is shared by every order n of the grid; i = ceil(P / m) + 1 block rows for orders up to P.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np
import scipy.linalg
import torch

from mop.filters.subspace import _lstsq_right, block_hankel
from mop.identify.arx import means
from mop.identify.linear import IDENTIFIERS, Arrays, FittedPredictor, LinearModel

RIDGE = 1e-8  # relative, as mop.filters.subspace: times the number of Hankel columns


def block_rows(max_order: int, output_dim: int) -> int:
    return math.ceil(max_order / output_dim) + 1


def columns(data: Arrays, i: int) -> int:
    """Block Hankel columns of the record: sum over trajectories of T_i + 1 - 2 i + 1 (those long enough)."""
    return sum(max(len(y) - 2 * i + 1, 0) for y, _ in data)


def _hankels(data: Arrays, i: int) -> tuple[torch.Tensor, torch.Tensor, list[int]]:
    """(Hy (2 i m, J), Hu (2 i k, J), columns per trajectory) over the trajectories with >= 2 i outputs."""
    hy, hu, cols = [], [], []
    for y, u in data:
        if len(y) >= 2 * i:
            hy.append(block_hankel(torch.from_numpy(y)[None], 2 * i)[0])
            hu.append(block_hankel(torch.from_numpy(u)[None], 2 * i)[0])
            cols.append(hy[-1].shape[-1])
    return torch.cat(hy, -1), torch.cat(hu, -1), cols


def project(data: Arrays, i: int) -> tuple[torch.Tensor, torch.Tensor, list[int]]:
    """(S (i m,), Vh (i m, J), columns per trajectory): the SVD of the oblique projection O = L_w W_p."""
    Hy, Hu, cols = _hankels(data, i)
    m, k = data[0][0].shape[1], data[0][1].shape[1]
    Wp = torch.cat([Hu[: i * k], Hy[: i * m]])  # (i (k + m), J)
    Uf, Yf = Hu[i * k :], Hy[i * m :]
    ridge = RIDGE * Wp.shape[-1]
    L = _lstsq_right(Yf[None], torch.cat([Wp, Uf])[None], ridge)[0]  # (i m, i (k + m) + i k)
    O = L[:, : Wp.shape[0]] @ Wp  # (i m, J)
    _, S, Vh = torch.linalg.svd(O, full_matrices=False)
    return S, Vh, cols


def kalman_gain(A: np.ndarray, C: np.ndarray, W: np.ndarray, E: np.ndarray) -> np.ndarray:
    """K (n, m) of the steady-state predictor for state / output residuals W (n, N), E (m, N)."""
    N = W.shape[1]
    Q, S, R = W @ W.T / N, W @ E.T / N, E @ E.T / N
    try:
        P = scipy.linalg.solve_discrete_are(A.T, C.T, Q, R, s=S)
        K = (A @ P @ C.T + S) @ np.linalg.inv(C @ P @ C.T + R)
        if np.isfinite(K).all():
            return K
    except (np.linalg.LinAlgError, ValueError):
        pass
    return W @ E.T @ np.linalg.pinv(E @ E.T)


def realize(
    data: Arrays, S: torch.Tensor, Vh: torch.Tensor, cols: list[int], order: int, i: int
) -> tuple[np.ndarray, ...]:
    """(A (n, n), B (n, k), C (m, n), K (n, m)) of order n = `order` from the shared SVD."""
    X = S[:order, None].sqrt() * Vh[:order]  # (n, J)
    used = [(y, u) for y, u in data if len(y) >= 2 * i]
    parts = torch.split(X, cols, dim=-1)  # per trajectory: states at times i..i+j-1
    Xm = torch.cat([x[:, :-1] for x in parts], -1)
    Xp = torch.cat([x[:, 1:] for x in parts], -1)
    Y = torch.cat([torch.from_numpy(y[i : i + j - 1]).T for (y, _), j in zip(used, cols, strict=True)], -1)
    U = torch.cat([torch.from_numpy(u[i : i + j - 1]).T for (_, u), j in zip(used, cols, strict=True)], -1)
    ridge = RIDGE * X.shape[-1]
    Z = torch.cat([Xm, U])  # (n + k, N)
    AB = _lstsq_right(Xp[None], Z[None], ridge)[0]  # (n, n + k)
    C = _lstsq_right(Y[None], Xm[None], ridge)[0]  # (m, n)
    W, E = (Xp - AB @ Z).numpy(), (Y - C @ Xm).numpy()
    A, B, C = AB[:, :order].numpy(), AB[:, order:].numpy(), C.numpy()
    return A, B, C, kalman_gain(A, C, W, E)


def output_offset(model: LinearModel, data: Arrays) -> np.ndarray:
    """delta (m,): the constant that, added to d, best explains the record by least squares together with an
    initial state per trajectory (projected out): y_t - free_t = C A^t x0 + delta, free the deterministic
    response from x = 0. The estimation means are not the model's equilibrium (they differ from it by the
    sample mean of the response, O(std / sqrt(N))), which without it takes one more order to absorb."""
    m = model.C.shape[0]
    G, h = np.zeros((m, m)), np.zeros(m)
    for y, u in data:
        free = model.rollout(np.zeros((1, model.state_dim)), u[None], len(y))[0]  # (L, m)
        rows, AL = [], np.eye(model.state_dim)
        for _ in range(len(y)):
            rows.append(model.C @ AL)
            AL = model.A @ AL
        O, J = np.concatenate(rows), np.tile(np.eye(m), (len(y), 1))  # (L m, n), (L m, m)
        if not (np.isfinite(O).all() and np.isfinite(free).all()):
            return np.zeros(m)
        Q = np.linalg.svd(O, full_matrices=False)[0]  # orthonormal basis of what x0 explains
        PJ, Pr = J - Q @ (Q.T @ J), (y - free).reshape(-1) - Q @ (Q.T @ (y - free).reshape(-1))
        G, h = G + PJ.T @ PJ, h + PJ.T @ Pr
    return np.linalg.lstsq(G, h, rcond=None)[0]


def n4sid_model(A, B, C, K, y_mean: np.ndarray, u_mean: np.ndarray, data: Arrays) -> LinearModel:  # noqa: ANN001
    """The innovation model in the data's units: b = -B u_mean, d = y_mean + output_offset, x0 = 0."""
    model = LinearModel(A=A, B=B, C=C, K=K, b=-B @ u_mean, d=y_mean.copy(), x0=np.zeros(A.shape[0]))
    return replace(model, d=y_mean + output_offset(model, data))


class N4SID:
    """The "n4sid" identifier: grid n = 1..P, i = ceil(P / m) + 1 block rows."""

    kind = "n4sid"
    lag_state = False

    @staticmethod
    def candidates(max_order: int, input_dim: int) -> list[dict[str, int]]:
        return [{"n": n} for n in range(1, max_order + 1)]

    @staticmethod
    def size(orders: dict[str, int], output_dim: int, input_dim: int) -> int:
        return orders["n"]

    @staticmethod
    def feasible(data: Arrays, orders: dict[str, int], max_order: int) -> bool:
        """Whether the Hankel matrices have at least twice as many columns as the projection has regressors
        (2 i k + i m), with the block rows of the grid up to max_order."""
        m, k = data[0][0].shape[1], data[0][1].shape[1]
        i = block_rows(max_order, m)
        return columns(data, i) >= 2 * (2 * i * k + i * m) and orders["n"] <= i * m

    @staticmethod
    def fit_grid(
        data: Arrays, candidates: list[dict[str, int]], info: dict[str, Any], max_order: int
    ) -> list[FittedPredictor]:
        y_mean, u_mean = means(data)
        m, k = len(y_mean), len(u_mean)
        i = block_rows(max_order, m)
        centered = [(y - y_mean, u - u_mean) for y, u in data]
        S, Vh, cols = project(centered, i)
        out = []
        for orders in candidates:
            A, B, C, K = realize(centered, S, Vh, cols, orders["n"], i)
            model = n4sid_model(A, B, C, K, y_mean, u_mean, data)
            fitted = {"n": orders["n"], "block_rows": i}
            out.append(FittedPredictor(N4SID.kind, fitted, model, m, k, dict(info)))
        return out


IDENTIFIERS.add(N4SID.kind, N4SID)
