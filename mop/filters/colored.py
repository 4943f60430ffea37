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
from mop.systems.base import StateSpace, Trajectories


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


@PREDICTORS.register("kalman-colored", needs_system=True)
class ColoredNoiseKalmanPredictor:
    """Kalman filter on the noise-augmented state ("kalman-colored"): the optimal predictor for the
    colored-noise family when the system is known. Needs params A, C, P0, noise_var_w, noise_var_v (B,),
    color_window (B,) (all systems of one batch share the window)."""

    name = "kalman-colored"

    def __init__(self, name: str = "kalman-colored") -> None:
        self.name = name

    def _model(self, traj: Trajectories) -> StateSpace:
        need = ("A", "C", "noise_var_w", "noise_var_v", "color_window")
        missing = [k for k in need if k not in traj.params]
        if missing:
            raise MopError(
                f"kalman-colored needs linear-system parameters {missing} in the trajectories; "
                "use it on a linear family (colored-noise)"
            )
        p = traj.params
        windows = p["color_window"].unique()
        if windows.numel() != 1:
            raise MopError(f"kalman-colored: systems of one batch must share color_window, got {windows}")
        P0 = p["P0"].double() if "P0" in p else None
        return colored_state_space(
            p["A"].double(),
            p["C"].double(),
            p["noise_var_w"].double(),
            p["noise_var_v"].double(),
            int(windows.item()),
            P0,
        )

    def predict(self, traj: Trajectories) -> Tensor:
        yhat, _ = gaussian_filter(self._model(traj), kalman_step, traj.y.double())
        return yhat.to(traj.y.dtype)

    def forecast(self, traj: Trajectories, steps: int) -> Tensor:
        """(B, T+1, K, m): the augmented model's Kalman forecast (mop.filters.gaussian.gaussian_forecast)."""
        return filter_forecast(self._model(traj), kalman_step, traj, steps)[0]
