"""Kalman filter one-step predictions for linear Gaussian systems, batched over systems (loop over time only).

    x_{t+1} = A x_t + B u_t + w_t,  w_t ~ N(0, Q)      y_t = C x_t + v_t,  v_t ~ N(0, R)      x_0 ~ N(x0, P0)

(B u_t absent for systems without inputs). The filter is mop.filters.gaussian's core with the linear time
update (kalman_step):

    yhat_t = C m_t,   S_t = C P_t C^T + R                  (predictive mean and covariance of y_t)
    condition on y_t (Joseph form), then  m <- A m + B u_t,  P <- A P A^T + Q

The steady-state predictor uses the fixed point P of the filter Riccati equation (DARE)
    P = A P A^T - A P C^T (C P C^T + R)^{-1} C P A^T + Q,
solved batched in torch by structured doubling (tested against scipy.linalg.solve_discrete_are).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from mop.errors import MopError
from mop.filters.gaussian import GaussianFilterPredictor, condition_on, gaussian_filter, kalman_step
from mop.predictors import PREDICTORS
from mop.systems.base import linear_state_space

Array = Tensor | np.ndarray


@dataclass(frozen=True)
class KalmanResult:
    """yhat (B, T, m): C m_t, predictive means;  S (B, T, m, m): predictive covariances C P_t C^T + R."""

    yhat: Array
    S: Array


def _to_torch(*arrays: Array | None) -> tuple[list[Tensor | None], bool]:
    is_numpy = isinstance(arrays[0], np.ndarray)
    out = [None if a is None else torch.as_tensor(a) for a in arrays]
    dtype = torch.promote_types(out[0].dtype, torch.float32)
    return [None if a is None else a.to(dtype) for a in out], is_numpy


def _check_shapes(A: Tensor, C: Tensor, Q: Tensor, R: Tensor, y: Tensor) -> None:
    B, n = A.shape[0], A.shape[-1]
    m = C.shape[1]
    expected = {"A": (B, n, n), "C": (B, m, n), "Q": (B, n, n), "R": (B, m, m)}
    for name, M in zip("ACQR", (A, C, Q, R), strict=True):
        if tuple(M.shape) != expected[name]:
            raise MopError(
                f"kalman: {name} has shape {tuple(M.shape)}, expected {expected[name]}; fix the inputs"
            )
    if y.ndim != 3 or y.shape[0] != B or y.shape[2] != m:
        raise MopError(f"kalman: y has shape {tuple(y.shape)}, expected ({B}, T, {m}); fix the inputs")


def kalman_filter(
    A: Array,
    C: Array,
    Q: Array,
    R: Array,
    y: Array,
    x0: Array | None = None,
    P0: Array | None = None,
    B: Array | None = None,
    u: Array | None = None,
) -> KalmanResult:
    """Kalman one-step predictions and their covariances.

    A (B, n, n), C (B, m, n), Q (B, n, n), R (B, m, m) symmetric positive definite, y (B, T, m),
    x0 (B, n) prior mean of x_0 (default 0), P0 (B, n, n) prior covariance (default I),
    B (B, n, k) input matrix and u (B, T, k) inputs (u_t acts between y_t and y_{t+1}), both or neither.
    Returns KalmanResult(yhat (B, T, m), S (B, T, m, m)); numpy in -> numpy out.
    """
    (A, C, Q, R, y, x0, P0, B_in, u), is_numpy = _to_torch(A, C, Q, R, y, x0, P0, B, u)
    _check_shapes(A, C, Q, R, y)
    if (B_in is None) != (u is None):
        raise MopError("kalman: give both the input matrix B and the inputs u, or neither")
    batch, n = A.shape[0], A.shape[-1]
    x0 = torch.zeros(batch, n, dtype=A.dtype) if x0 is None else x0
    P0 = torch.eye(n, dtype=A.dtype).expand(batch, n, n) if P0 is None else P0
    model = linear_state_space(A, C, Q, R, P0, B_in, x0)
    yhat, S = gaussian_filter(model, kalman_step, y.double(), None if u is None else u.double())
    yhat, S = yhat.to(A.dtype), S.to(A.dtype)
    if is_numpy:
        return KalmanResult(yhat.numpy(), S.numpy())
    return KalmanResult(yhat, S)


def kalman_predict(
    A: Array,
    C: Array,
    Q: Array,
    R: Array,
    y: Array,
    x0: Array | None = None,
    P0: Array | None = None,
    B: Array | None = None,
    u: Array | None = None,
) -> Array:
    """yhat (B, T, m) with yhat[:, t] = C x_{t|t-1} = E[y_t | y_{<t}, u_{<t}]; shapes as kalman_filter."""
    return kalman_filter(A, C, Q, R, y, x0, P0, B, u).yhat


def solve_filter_dare(
    A: Tensor, C: Tensor, Q: Tensor, R: Tensor, num_iters: int = 60, tol: float = 1e-12
) -> Tensor:
    """Steady-state prior covariance P (B, n, n) of P = A P A^T - A P C^T (C P C^T + R)^{-1} C P A^T + Q.

    Structured doubling (Chu et al. 2004) on the dual control DARE (A -> A^T, B -> C^T):
        F_0 = A^T, G_0 = C^T R^{-1} C, H_0 = Q,  W = (I + G H)^{-1}
        F <- F W F,  G <- G + F W G F^T,  H <- H + F^T H W F;   H -> P quadratically.
    """
    eye = torch.eye(A.shape[-1], dtype=A.dtype, device=A.device)
    F, G, H = A.mT, C.mT @ torch.cholesky_solve(C, torch.linalg.cholesky(R)), Q
    for _ in range(num_iters):
        W_F = torch.linalg.solve(eye + G @ H, F)  # (B, n, n) = (I + G H)^{-1} F
        W_G = torch.linalg.solve(eye + G @ H, G)
        H_new = H + F.mT @ H @ W_F
        G, F = G + F @ W_G @ F.mT, F @ W_F
        done = (H_new - H).abs().amax() <= tol * (1 + H_new.abs().amax())
        H = 0.5 * (H_new + H_new.mT)
        if done:
            break
    return H


def steady_state_gain(A: Tensor, C: Tensor, Q: Tensor, R: Tensor) -> tuple[Tensor, Tensor]:
    """(K (B, n, m), P (B, n, n)): predictor gain K = A P C^T (C P C^T + R)^{-1} at the DARE solution P."""
    P = solve_filter_dare(A, C, Q, R)
    S = C @ P @ C.mT + R  # (B, m, m)
    K = A @ torch.cholesky_solve(C @ P, torch.linalg.cholesky(S)).mT  # (B, n, m)
    return K, P


def steady_state_predict(A: Tensor, C: Tensor, K: Tensor, y: Tensor, x0: Tensor | None = None) -> Tensor:
    """Innovation-form predictor m_{t+1} = A m_t + K (y_t - C m_t); returns yhat_t = C m_t (B, T, m)."""
    m = torch.zeros(A.shape[0], A.shape[-1], dtype=A.dtype, device=A.device) if x0 is None else x0
    F = A - K @ C  # (B, n, n)
    preds = []
    for t in range(y.shape[1]):
        preds.append((C @ m[..., None])[..., 0])
        m = (F @ m[..., None] + K @ y[:, t, :, None])[..., 0]
    return torch.stack(preds, dim=1)


@PREDICTORS.register("kalman", needs_system=True, gaussian=True, linear_model=True, default_reference=True)
class KalmanPredictor(GaussianFilterPredictor):
    """The Kalman filter that knows each system: its family's (linear) StateSpace, x_0 ~ N(0, P0), or for
    data without a family a known linear model (mop.systems.base.linear_model_from_params).
    On switching systems the family's model switches too (the authors' KF that keeps system 1 is the
    predictor "kalman-system1" of mop.filters.system1)."""

    name = "kalman"

    def __init__(self) -> None:
        super().__init__(kalman_step, project=False, name="kalman")


def innovation_floor(A: Array, C: Array, Q: Array, R: Array) -> Tensor:
    """(B,) irreducible one-step error E||y_t - yhat_t||^2 of the optimal (steady-state) predictor:
    trace(C P C^T + R), P the filter DARE solution (scipy.linalg.solve_discrete_are per system).

    A (B, n, n), C (B, m, n), Q (B, n, n), R (B, m, m). The paper's metric is the mean of ||e_t||_2, and by
    Jensen E||e|| <= sqrt(E||e||^2), so the floor of the paper's error curve is approximately (and at most)
    sqrt(innovation_floor).
    """
    from scipy.linalg import solve_discrete_are

    (A, C, Q, R), _ = _to_torch(A, C, Q, R)
    A, C, Q, R = (M.detach().cpu().double().numpy() for M in (A, C, Q, R))
    out = [
        np.trace(c @ solve_discrete_are(a.T, c.T, q, r) @ c.T + r)
        for a, c, q, r in zip(A, C, Q, R, strict=True)
    ]
    return torch.tensor(out, dtype=torch.float64)


def optimal_mse_curve(
    A: Array, C: Array, Q: Array, R: Array, horizon: int, P0: Array | None = None
) -> Tensor:
    """(B, horizon + 1) E||y_t - yhat_t||^2 = trace(S_t), S_t = C P_t C^T + R, of the Kalman filter started at
    P_0 = P0 (default I) for t = 0..horizon: the error floor of any predictor at each t when x_0 ~ N(0, P0).
    Shapes as kalman_filter; its values do not depend on the outputs. trace(S_t) -> innovation_floor as t
    grows; sqrt(trace S_t) is (by Jensen) an upper bound near the floor of the paper's mean ||e_t||_2 curve.
    """
    S = optimal_covariances(A, C, Q, R, horizon, P0)  # (B, T+1, m, m)
    return S.diagonal(dim1=-2, dim2=-1).sum(-1)


def optimal_covariances(
    A: Array, C: Array, Q: Array, R: Array, horizon: int, P0: Array | None = None
) -> Tensor:
    """(B, horizon + 1, m, m) innovation covariances S_t = C P_t C^T + R of the Kalman filter started at
    P_0 = P0 (default I): the optimal one-step error y_t - yhat_t is N(0, S_t) for t = 0..horizon."""
    (A, C, Q, R, P0), _ = _to_torch(A, C, Q, R, P0)
    B, n = A.shape[0], A.shape[-1]
    P = torch.eye(n, dtype=A.dtype).expand(B, n, n) if P0 is None else P0
    m, zero_y = A.new_zeros(B, n), A.new_zeros(B, C.shape[1])
    out = []
    for _ in range(horizon + 1):
        _, P, S = condition_on(m, P, zero_y, C, R)
        out.append(S)
        P = A @ P @ A.mT + Q
    return torch.stack(out, dim=1)


def expected_norm(S: Tensor, num_samples: int = 1000, seed: int = 0) -> Tensor:
    """E||e||_2 for e ~ N(0, S) by Monte Carlo (seeded): S (..., m, m) -> (...,), float64.

    The metric of the paper's error curves (mean ||yhat_t - y_t||), so the optimum drawn beside them is in
    their own units: sqrt(trace S), the RMS, is larger by Jensen's inequality. Common random numbers: every
    S uses the same standard normal draws z, e = L z with S = L L^T.
    """
    S = torch.as_tensor(S, dtype=torch.float64)
    m = S.shape[-1]
    L = torch.linalg.cholesky(S).reshape(-1, m, m)  # (N, m, m), N = prod(...)
    g = torch.Generator().manual_seed(seed)
    z = torch.randn(num_samples, m, generator=g, dtype=torch.float64)  # (K, m)
    chunk = max(1, 2**22 // (num_samples * m))  # ~32 MB of draws at a time
    out = [
        torch.linalg.vector_norm(torch.einsum("nij,kj->nki", L[i : i + chunk], z), dim=-1).mean(-1)
        for i in range(0, L.shape[0], chunk)
    ]  # each (n,)
    return torch.cat(out).reshape(S.shape[:-2])
