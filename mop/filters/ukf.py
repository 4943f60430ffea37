"""Unscented Kalman filter one-step predictions, batched over systems (a loop over time only).

Time update by the unscented transform with 2n + 1 sigma points (Julier/Merwe scaling):

    lambda = alpha^2 (n + kappa) - n,  X = [m, m + sqrt(n + lambda) L_i, m - sqrt(n + lambda) L_i],  L L^T = P
    m <- sum_i Wm_i f(X_i, u),  P <- sum_i Wc_i (f(X_i) - m)(f(X_i) - m)^T + Q,
    Wm_0 = lambda / (n + lambda), Wc_0 = Wm_0 + 1 - alpha^2 + beta, Wm_i = Wc_i = 1 / (2 (n + lambda)).

The output map is linear (y = C x + v), for which the unscented measurement update is exactly the
Kalman update, so conditioning reuses mop.filters.ekf._condition_on.
With project=True ("ukf") the family's state projection (the quadrotor's clipping) is applied to m_0 and to
each predicted mean, P left as it is; project=False gives "ukf-noclip". Unlike mop's EKF, which copies the
authors' EKF, the UKF (not in the paper) does not also clip the posterior mean before the time update: that
would raise its error over t in [20, 50) on mop's generator (N = 1000) from 0.50 to 0.65.
On a linear system the UKF equals the Kalman filter.
"""

from __future__ import annotations

import torch
from torch import Tensor

from mop.filters.ekf import Dynamics, Projection, _condition_on, identity, system_model
from mop.systems.base import Trajectories


def sigma_points(
    m: Tensor, P: Tensor, alpha: float, beta: float, kappa: float
) -> tuple[Tensor, Tensor, Tensor]:
    """X (B, 2n+1, n), Wm (2n+1,), Wc (2n+1,) for N(m, P); m (B, n), P (B, n, n)."""
    n = m.shape[-1]
    lam = alpha**2 * (n + kappa) - n
    L = torch.linalg.cholesky((n + lam) * P)  # (B, n, n)
    X = torch.cat([m[:, None], m[:, None] + L.mT, m[:, None] - L.mT], dim=1)  # rows of L^T = columns of L
    Wm = torch.full((2 * n + 1,), 0.5 / (n + lam), dtype=m.dtype, device=m.device)
    Wm[0] = lam / (n + lam)
    Wc = Wm.clone()
    Wc[0] = Wm[0] + 1 - alpha**2 + beta
    return X, Wm, Wc


def _predict(
    m: Tensor, P: Tensor, u: Tensor | None, f: Dynamics, Q: Tensor, alpha: float, beta: float, kappa: float
) -> tuple[Tensor, Tensor]:
    """Unscented time update of N(m, P) through f, plus Q."""
    X, Wm, Wc = sigma_points(m, P, alpha, beta, kappa)  # (B, 2n+1, n)
    u_rep = None if u is None else u[:, None].expand(-1, X.shape[1], -1)  # (B, 2n+1, k)
    FX = f(X, u_rep)  # (B, 2n+1, n)
    m = torch.einsum("i,bin->bn", Wm, FX)
    D = FX - m[:, None]  # (B, 2n+1, n)
    P = torch.einsum("i,bin,bik->bnk", Wc, D, D) + Q
    return m, 0.5 * (P + P.mT)


def unscented_kalman_predict(
    f: Dynamics,
    C: Tensor,
    Q: Tensor,
    R: Tensor,
    m0: Tensor,
    P0: Tensor,
    y: Tensor,
    u: Tensor | None = None,
    alpha: float = 1.0,
    beta: float = 0.0,
    kappa: float = 0.0,
    project: Projection | None = None,
) -> Tensor:
    """One-step predictions yhat (B, T+1, m), shapes and `project` as in
    mop.filters.ekf.extended_kalman_predict."""
    project = project or identity
    m, P, preds = project(m0), P0, []
    for t in range(y.shape[1]):
        preds.append((C @ m[..., None])[..., 0])
        m, P = _condition_on(m, P, y[:, t], C, R)
        m, P = _predict(m, P, None if u is None else u[:, t], f, Q, alpha, beta, kappa)
        m = project(m)
    return torch.stack(preds, dim=1)


def ukf_predict(
    params: dict[str, Tensor],
    y: Tensor,
    u: Tensor | None = None,
    alpha: float = 1.0,
    beta: float = 0.0,
    kappa: float = 0.0,
    project: bool = True,
) -> Tensor:
    """UKF predictions (B, T+1, m) for systems described by `params` (quadrotor or linear), in float64."""
    model = system_model(params)
    p = {k: params[k].double() for k in ("C", "Q", "R", "P0")}
    u = None if u is None else u.double()
    proj = model.project if project else None
    return unscented_kalman_predict(
        model.f, p["C"], p["Q"], p["R"], model.m0, p["P0"], y.double(), u, alpha, beta, kappa, proj
    )


class UKFPredictor:
    """The unscented Kalman filter that knows each system's parameters (traj.params); project as in
    EKFPredictor ("ukf" clips its predicted mean, "ukf-noclip" does not)."""

    def __init__(
        self, alpha: float = 1.0, beta: float = 0.0, kappa: float = 0.0, project: bool = True
    ) -> None:
        self.alpha, self.beta, self.kappa, self.project = alpha, beta, kappa, project
        self.name = "ukf" if project else "ukf-noclip"

    def predict(self, traj: Trajectories) -> Tensor:
        yhat = ukf_predict(traj.params, traj.y, traj.u, self.alpha, self.beta, self.kappa, self.project)
        return yhat.to(traj.y.dtype)
