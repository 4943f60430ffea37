"""Kalman filter one-step predictions for linear Gaussian systems, batched over systems (loop over time only).

    x_{t+1} = A x_t + w_t,  w_t ~ N(0, Q)        y_t = C x_t + v_t,  v_t ~ N(0, R)        x_0 ~ N(x0, P0)

With m_t, P_t the prior mean / covariance of x_t given y_{<t}:

    yhat_t = C m_t,   S_t = C P_t C^T + R                  (predictive mean and covariance of y_t)
    condition on y_t:  K = P C^T S^{-1},  m <- m + K (y_t - C m),  P <- (I - K C) P (I - K C)^T + K R K^T
    predict:           m <- A m,  P <- A P A^T + Q

The steady-state predictor uses the fixed point P of the filter Riccati equation (DARE)
    P = A P A^T - A P C^T (C P C^T + R)^{-1} C P A^T + Q,
solved batched in torch by structured doubling (tested against scipy.linalg.solve_discrete_are).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from mop.errors import MopError
from mop.systems.base import Trajectories

Array = Tensor | np.ndarray
StepMatrices = Callable[[int], tuple[Tensor, Tensor]]  # t -> (A_t (B, n, n), C_t (B, m, n))


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


def _condition_on(m: Tensor, P: Tensor, y: Tensor, C: Tensor, R: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Measurement update, Joseph form. m (B, n), P (B, n, n), y (B, m) -> (m, P, S (B, m, m))."""
    S = C @ P @ C.mT + R  # (B, m, m)
    L = torch.linalg.cholesky(S)  # (B, m, m)
    K = torch.cholesky_solve(C @ P, L).mT  # (B, n, m) = P C^T S^{-1}
    m = m + (K @ (y - (C @ m[..., None])[..., 0])[..., None])[..., 0]
    I_KC = torch.eye(P.shape[-1], dtype=P.dtype, device=P.device) - K @ C  # (B, n, n)
    P = I_KC @ P @ I_KC.mT + K @ R @ K.mT
    return m, P, S


def _predict(m: Tensor, P: Tensor, A: Tensor, Q: Tensor) -> tuple[Tensor, Tensor]:
    """Time update: m <- A m, P <- A P A^T + Q (symmetrized)."""
    P = A @ P @ A.mT + Q
    return (A @ m[..., None])[..., 0], 0.5 * (P + P.mT)


def kalman_loop(
    matrices: StepMatrices, Q: Tensor, R: Tensor, y: Tensor, x0: Tensor, P0: Tensor
) -> tuple[Tensor, Tensor]:
    """Time-varying KF: matrices(t) gives (A_t, C_t); y_t = C_t x_t, x_{t+1} = A_t x_t. Returns yhat, S."""
    m, P, preds, covs = x0, P0, [], []
    for t in range(y.shape[1]):
        A, C = matrices(t)
        preds.append((C @ m[..., None])[..., 0])
        m, P, S = _condition_on(m, P, y[:, t], C, R)
        covs.append(S)
        m, P = _predict(m, P, A, Q)
    return torch.stack(preds, dim=1), torch.stack(covs, dim=1)  # (B, T, m), (B, T, m, m)


def kalman_filter(
    A: Array, C: Array, Q: Array, R: Array, y: Array, x0: Array | None = None, P0: Array | None = None
) -> KalmanResult:
    """Kalman one-step predictions and their covariances.

    A (B, n, n), C (B, m, n), Q (B, n, n), R (B, m, m) symmetric positive definite, y (B, T, m),
    x0 (B, n) prior mean of x_0 (default 0), P0 (B, n, n) prior covariance (default I).
    Returns KalmanResult(yhat (B, T, m), S (B, T, m, m)); numpy in -> numpy out.
    """
    (A, C, Q, R, y, x0, P0), is_numpy = _to_torch(A, C, Q, R, y, x0, P0)
    _check_shapes(A, C, Q, R, y)
    B, n = A.shape[0], A.shape[-1]
    x0 = torch.zeros(B, n, dtype=A.dtype) if x0 is None else x0
    P0 = torch.eye(n, dtype=A.dtype).expand(B, n, n) if P0 is None else P0
    yhat, S = kalman_loop(lambda t: (A, C), Q, R, y, x0, P0)
    if is_numpy:
        return KalmanResult(yhat.numpy(), S.numpy())
    return KalmanResult(yhat, S)


def kalman_predict(
    A: Array, C: Array, Q: Array, R: Array, y: Array, x0: Array | None = None, P0: Array | None = None
) -> Array:
    """yhat (B, T, m) with yhat[:, t] = C x_{t|t-1} = E[y_t | y_{<t}]; see kalman_filter for the shapes."""
    return kalman_filter(A, C, Q, R, y, x0, P0).yhat


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


def _linear_params(traj: Trajectories) -> dict[str, Tensor]:
    missing = [k for k in ("A", "C", "Q", "R") if k not in traj.params]
    if missing:
        raise MopError(
            f"the Kalman predictor needs linear-system parameters {missing} in the trajectories; "
            "use it on a linear family"
        )
    p = {k: v.double() for k, v in traj.params.items() if v.is_floating_point()}
    B, n = p["A"].shape[0], p["A"].shape[-1]
    p.setdefault("P0", torch.eye(n, dtype=torch.float64).expand(B, n, n))
    return p


class KalmanPredictor:
    """The Kalman filter that knows each system (A, C, Q, R, P0 from traj.params; x_0 mean 0).

    On switching systems it keeps system 1's (A, C) throughout, as the authors' baseline does;
    `knows_switch=True` (name "kalman-switch") uses (A2, C2) from switch_time on, continuing its estimate.
    `steady_state=True` uses the constant DARE gain instead of the time-varying one.
    """

    def __init__(self, name: str = "kalman", steady_state: bool = False, knows_switch: bool = False) -> None:
        self.name, self.steady_state, self.knows_switch = name, steady_state, knows_switch

    def predict(self, traj: Trajectories) -> Tensor:
        p, y = _linear_params(traj), traj.y.double()
        if self.steady_state:
            K, _ = steady_state_gain(p["A"], p["C"], p["Q"], p["R"])
            return steady_state_predict(p["A"], p["C"], K, y).to(traj.y.dtype)
        return self.predict_distribution(traj)[0]

    def predict_distribution(self, traj: Trajectories) -> tuple[Tensor, Tensor]:
        """(mean, var) each (B, T+1, m): C m_t and diag(S_t) = diag(C P_t C^T + R) of the time-varying KF."""
        p, y = _linear_params(traj), traj.y.double()
        x0 = torch.zeros(p["A"].shape[:-1], dtype=torch.float64)
        yhat, S = kalman_loop(self._matrices(p, traj), p["Q"], p["R"], y, x0, p["P0"])
        return yhat.to(traj.y.dtype), torch.diagonal(S, dim1=-2, dim2=-1).to(traj.y.dtype)

    def _matrices(self, p: dict[str, Tensor], traj: Trajectories) -> StepMatrices:
        if not self.knows_switch:
            return lambda t: (p["A"], p["C"])
        if "switch_time" not in traj.params:
            raise MopError(
                "kalman-switch needs switching-system parameters (A2, C2, switch_time); "
                "use it on the switching family"
            )
        s = traj.params["switch_time"].to(torch.long)[:, None, None]  # (B, 1, 1)
        return lambda t: (torch.where(t >= s, p["A2"], p["A"]), torch.where(t >= s, p["C2"], p["C"]))


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
    (A, C, Q, R, P0), _ = _to_torch(A, C, Q, R, P0)
    B, n = A.shape[0], A.shape[-1]
    P = torch.eye(n, dtype=A.dtype).expand(B, n, n) if P0 is None else P0
    m, zero_y = A.new_zeros(B, n), A.new_zeros(B, C.shape[1])
    out = []
    for _ in range(horizon + 1):
        _, P, S = _condition_on(m, P, zero_y, C, R)
        out.append(S.diagonal(dim1=-2, dim2=-1).sum(-1))
        _, P = _predict(m, P, A, Q)
    return torch.stack(out, dim=1)
