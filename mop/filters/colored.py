"""The exact MMSE one-step predictor for linear systems driven by moving-sum (colored) noise.

The colored-noise family (mop.systems.linear.moving_sum_noise) draws, per system, a_k ~ N(0, q I_n) and
b_k ~ N(0, r I_m) i.i.d. for k = 0..T+W-1 (W = color_window) and sets

    w_t = a_t + ... + a_{t+W-1},   v_t = b_t + ... + b_{t+W-1},
    x_{t+1} = A x_t + w_t,         y_t = C x_t + v_t,           x_0 ~ N(0, P0) independent of the draws,

so w, v are stationary from t = 0 and w_t, w_{t+1} share W-1 draws. Augment the state with the draws that
are already "in flight",

    z_t = [x_t; a_t, ..., a_{t+W-2}; b_t, ..., b_{t+W-1}]          (n + (W-1) n + W m),

then z_{t+1} = A_aug z_t + G [a_{t+W-1}; b_{t+W}] and y_t = C_aug z_t exactly (no measurement noise):

    x_{t+1} = A x_t + (a_t + ... + a_{t+W-2}) + a_{t+W-1},   the a / b blocks shift by one, the new draw last;
    y_t     = C x_t + (b_t + ... + b_{t+W-1}).

The new draws are independent of z_t, so this is a standard state-space model with process noise covariance
Q_aug = G diag(q I, r I) G^T (positive semi-definite) and R_aug = 0. The Kalman filter on it
(mop.filters.gaussian.gaussian_filter) is the exact MMSE predictor E[y_t | y_{<t}]; its innovation covariance
S_t = C_aug P_t C_aug^T >= r I (the draw b_{t+W-1} is unobserved before t), so the Cholesky of S_t in
condition_on is always defined (for r > 0), with no jitter. Prior at t = 0:
z_0 ~ N(0, blockdiag(P0, q I, ..., r I, ...)). For W = 1 the model is x_{t+1} = A x_t + a_t,
y_t = C x_t + b_t:
the plain Kalman filter with Q = q I, R = r I.
"""

from __future__ import annotations

import torch
from torch import Tensor

from mop.errors import MopError
from mop.filters.gaussian import filter_forecast, gaussian_filter, kalman_step
from mop.predictors import PREDICTORS
from mop.systems.base import StateSpace, Trajectories, require_params

CHUNK = 64  # systems per colored_filter call in the predictor (their covariances stay in cache)


def augmented_model(
    A: Tensor, C: Tensor, var_w: Tensor, var_v: Tensor, window: int, P0: Tensor
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """(A_aug (B, N, N), C_aug (B, m, N), Q_aug (B, N, N), P0_aug (B, N, N)), N = n + (W-1) n + W m.

    A (B, n, n), C (B, m, n), var_w, var_v (B,) per-draw variances q, r, P0 (B, n, n) prior covariance of x_0.
    """
    if window < 1:
        raise MopError(f"kalman-colored: color_window must be >= 1, got {window}")
    B, n, m, W = A.shape[0], A.shape[-1], C.shape[-2], window
    na, N = (W - 1) * n, n + (W - 1) * n + W * m
    kw = {"dtype": A.dtype, "device": A.device}
    I_n, I_m = torch.eye(n, **kw), torch.eye(m, **kw)
    A_aug = torch.zeros(B, N, N, **kw)
    A_aug[:, :n, :n] = A
    for j in range(W - 1):
        A_aug[:, :n, n + j * n : n + (j + 1) * n] = I_n  # x_{t+1} gets a_t..a_{t+W-2}
    for j in range(W - 2):  # a-block j of z_{t+1} = a-block j + 1 of z_t
        A_aug[:, n + j * n : n + (j + 1) * n, n + (j + 1) * n : n + (j + 2) * n] = I_n
    off = n + na
    for j in range(W - 1):  # b-block j of z_{t+1} = b-block j + 1 of z_t
        A_aug[:, off + j * m : off + (j + 1) * m, off + (j + 1) * m : off + (j + 2) * m] = I_m
    C_aug = torch.cat([C, torch.zeros(B, m, na, **kw), I_m.repeat(1, W).expand(B, m, W * m)], dim=-1)
    G = torch.zeros(N, n + m, **kw)  # new draws [a_{t+W-1}; b_{t+W}] -> z_{t+1}
    G[:n, :n] = I_n  # into x_{t+1}
    if W > 1:
        G[n + na - n : n + na, :n] = I_n  # last a-block
    G[N - m :, n:] = I_m  # last b-block
    noise = torch.diag_embed(torch.cat([var_w[:, None].expand(B, n), var_v[:, None].expand(B, m)], dim=-1))
    Q_aug = G @ noise @ G.mT
    prior = torch.cat(
        [var_w[:, None].expand(B, na), var_v[:, None].expand(B, W * m)], dim=-1
    )  # (B, N - n) variances of the in-flight draws
    P0_aug = torch.diag_embed(torch.cat([torch.zeros(B, n, **kw), prior], dim=-1))
    P0_aug[:, :n, :n] = P0
    return A_aug, C_aug, Q_aug, P0_aug


def colored_kalman_filter(
    A: Tensor, C: Tensor, var_w: Tensor, var_v: Tensor, window: int, y: Tensor, P0: Tensor | None = None
) -> tuple[Tensor, Tensor]:
    """(yhat (B, T, m), S (B, T, m, m)): E[y_t | y_{<t}] and its error covariance under moving-sum noise.

    A (B, n, n), C (B, m, n), var_w, var_v (B,) per-draw variances, y (B, T, m), P0 (B, n, n) (default I).
    """
    return gaussian_filter(colored_state_space(A, C, var_w, var_v, window, P0), kalman_step, y)


def colored_state_space(
    A: Tensor, C: Tensor, var_w: Tensor, var_v: Tensor, window: int, P0: Tensor | None = None
) -> StateSpace:
    """The augmented linear StateSpace (A_aug, C_aug, Q_aug, R_aug = 0, z_0 ~ N(0, P0_aug)); shapes as
    colored_kalman_filter."""
    B, n, m = A.shape[0], A.shape[-1], C.shape[-2]
    P0 = torch.eye(n, dtype=A.dtype, device=A.device).expand(B, n, n) if P0 is None else P0
    A_aug, C_aug, Q_aug, P0_aug = augmented_model(A, C, var_w, var_v, window, P0)
    R_aug = torch.zeros(B, m, m, dtype=A.dtype, device=A.device)
    z0 = torch.zeros(B, A_aug.shape[-1], dtype=A.dtype, device=A.device)
    return StateSpace(
        f=lambda x, u, t: x @ A_aug.mT,
        C=C_aug,
        Q=Q_aug,
        R=R_aug,
        m0=z0,
        P0=P0_aug,
        jacobian=lambda x, u, t: A_aug,
    )


class ShiftRegister:
    """The augmented model's matrices applied by their structure (no N x N products with A_aug or C_aug).

    Rows of z: x (n), then W-1 a-blocks (n each), then W b-blocks (m each). A_aug M: the x rows get
    A M_x + the sum of the a-blocks, every other block takes the next block's rows, the last a- and b-block
    get 0. C_aug M = C M_x + the sum of the b-blocks. A (B, n, n), C (B, m, n)."""

    def __init__(self, A: Tensor, C: Tensor, window: int) -> None:
        self.A, self.C, self.W = A, C, window
        self.n, self.m = A.shape[-1], C.shape[-2]
        self.off = self.n * window  # first b row: n + (W-1) n

    def rows_A(self, M: Tensor, dim: int = 1) -> Tensor:
        """A_aug M for M (B, N, k), or M A_aug^T for M (B, k, N) with dim=2."""
        n, m, W, off = self.n, self.m, self.W, self.off
        rows = lambda lo, hi: M.narrow(dim, lo, hi - lo)  # noqa: E731
        A_x = self.A @ rows(0, n) if dim == 1 else rows(0, n) @ self.A.mT
        parts = [A_x + rows(n, off).unflatten(dim, (W - 1, n)).sum(dim)]
        zeros = lambda size: M.new_zeros(M.shape[:dim] + (size,) + M.shape[dim + 1 :])  # noqa: E731
        if W > 1:
            parts += [rows(2 * n, off), zeros(n)]  # a-block j <- a-block j + 1, the last 0
        parts += [rows(off + m, M.shape[dim]), zeros(m)]  # b-block j <- b-block j + 1, the last 0
        return torch.cat(parts, dim=dim)

    def rows_C(self, M: Tensor, dim: int = 1) -> Tensor:
        """C_aug M for M (B, N, k) -> (B, m, k), or M C_aug^T for M (B, k, N) with dim=2 -> (B, k, m)."""
        n, N = self.n, M.shape[dim]
        x, b = M.narrow(dim, 0, n), M.narrow(dim, self.off, N - self.off)
        C_x = self.C @ x if dim == 1 else x @ self.C.mT
        return C_x + b.unflatten(dim, (self.W, self.m)).sum(dim)

    def add_Q(self, P: Tensor, var_w: Tensor, var_v: Tensor) -> None:
        """P += Q_aug in place: q on the (x, x), (x, a_last), (a_last, x), (a_last, a_last) diagonals (the new
        draw a_{t+W-1} enters x and the last a-block), r on the (b_last, b_last) diagonal."""
        n, m, N = self.n, self.m, P.shape[-1]
        ends = [0] + ([self.off - n] if self.W > 1 else [])
        for i in ends:
            for j in ends:
                P[:, i : i + n, j : j + n].diagonal(dim1=-2, dim2=-1).add_(var_w[:, None])
        P[:, N - m :, N - m :].diagonal(dim1=-2, dim2=-1).add_(var_v[:, None])


def colored_filter(
    A: Tensor,
    C: Tensor,
    var_w: Tensor,
    var_v: Tensor,
    window: int,
    y: Tensor,
    P0: Tensor | None = None,
    steps: int = 1,
) -> tuple[Tensor, Tensor]:
    """The Kalman filter on the augmented model (gaussian_filter with kalman_step on colored_state_space,
    equal to rounding) at O(N^2 (n + m)) per step instead of O(N^3), by its shift-register structure:

        CP = C_aug P,  S = CP C_aug^T,  K = CP^T S^{-1},  m <- m + K (y - C_aug m),
        P <- P - K CP   (Joseph's form with R_aug = 0 and the optimal gain),
        m <- A_aug m,   P <- (A_aug P) A_aug^T + Q_aug.

    Differs on purpose from the generic core: no Joseph form and no symmetrisation (each is an N x N
    product or pass; tests/test_colored.py bounds the difference by 1e-10 over 100 steps).
    Returns (forecast means (B, T+1, K, m), NaN where t + j > T; S (B, T+1, m, m)): j = 0 is E[y_t | y_<t],
    j >= 1 the mean C_aug A_aug^j m_t with no measurement (K = steps). Shapes as colored_kalman_filter.
    """
    B, T1, m_out = y.shape
    P0 = torch.eye(A.shape[-1], dtype=A.dtype, device=A.device).expand(B, -1, -1) if P0 is None else P0
    _, _, _, P = augmented_model(A, C, var_w, var_v, window, P0)
    reg = ShiftRegister(A, C, window)
    mean = torch.zeros(B, P.shape[-1], 1, dtype=A.dtype, device=A.device)  # (B, N, 1)
    out = y.new_full((B, T1, steps, m_out), float("nan"))
    covs = []
    for t in range(T1):
        ahead, last = mean, min(steps, T1 - t)
        for j in range(last):
            out[:, t, j] = reg.rows_C(ahead)[..., 0]
            if j + 1 < last:
                ahead = reg.rows_A(ahead)
        CP = reg.rows_C(P)  # (B, m, N)
        S = reg.rows_C(CP, dim=2)  # (B, m, m) = C_aug P C_aug^T
        covs.append(S)
        K = torch.cholesky_solve(CP, torch.linalg.cholesky(S)).mT  # (B, N, m) = P C_aug^T S^{-1}
        mean = reg.rows_A(mean + K @ (y[:, t, :, None] - out[:, t, 0, :, None]))
        P = reg.rows_A(reg.rows_A(torch.baddbmm(P, K, CP, alpha=-1)), dim=2)  # A_aug (P - K CP) A_aug^T
        reg.add_Q(P, var_w, var_v)
    return out, torch.stack(covs, dim=1)


@PREDICTORS.register("kalman-colored", needs_system=True)
class ColoredNoiseKalmanPredictor:
    """Kalman filter on the noise-augmented state ("kalman-colored"): the optimal predictor for the
    colored-noise family when the system is known. Needs params A, C, P0, noise_var_w, noise_var_v (B,),
    color_window (B,) (LinearParams has them; all systems of one batch share the window)."""

    name = "kalman-colored"

    def __init__(self, name: str = "kalman-colored") -> None:
        self.name = name

    def _params(self, traj: Trajectories) -> dict:
        """A, C, var_w, var_v, P0 (float64) and window of colored_filter, checked."""
        require_params(
            traj.params, ("A", "C", "P0", "noise_var_w", "noise_var_v", "color_window"), by=self.name
        )
        p = traj.params
        windows = p.color_window.unique()
        if windows.numel() != 1:
            raise MopError(f"kalman-colored: systems of one batch must share color_window, got {windows}")
        return {
            "A": p.A.double(),
            "C": p.C.double(),
            "var_w": p.noise_var_w.double(),
            "var_v": p.noise_var_v.double(),
            "window": int(windows.item()),
            "P0": p.P0.double(),
        }

    def predict(self, traj: Trajectories) -> Tensor:
        return self.forecast(traj, 1)[:, :, 0]

    def forecast(self, traj: Trajectories, steps: int) -> Tensor:
        """(B, T+1, K, m): the augmented model's Kalman forecast, C_aug A_aug^j m_t (colored_filter, systems
        in chunks of CHUNK that stay in cache)."""
        p = self._params(traj)
        y = traj.y.double()
        parts = []
        for i in range(0, y.shape[0], CHUNK):
            part = {k: v[i : i + CHUNK] if torch.is_tensor(v) and v.ndim else v for k, v in p.items()}
            parts.append(colored_filter(y=y[i : i + CHUNK], steps=steps, **part)[0])
        return torch.cat(parts).to(traj.y.dtype)

    def reference_forecast(self, traj: Trajectories, steps: int) -> Tensor:
        """forecast by the generic core: gaussian_forecast with kalman_step on the dense augmented model
        (colored_state_space), O(N^3) per step; the reference of the tests."""
        p = self._params(traj)
        model = colored_state_space(**p)  # A, C, var_w, var_v, window, P0
        return filter_forecast(model, kalman_step, traj, steps)[0]
