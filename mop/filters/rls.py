"""Recursive least squares autoregression, one RLS per output dimension, batched over systems.

Order p, output i: y^i_{t+1} ~ theta^T phi_t with phi_t = [y^i_t, y^i_{t-1}, ..., y^i_{t-p+1}].
With theta_0 = 0, P_0 = I and forgetting factor 1, after the pairs (phi_s, y_{s+1}) for s < t the estimate is
the ridge solution theta = (I + sum phi phi^T)^{-1} sum phi y, updated by

    k = P phi / (1 + phi^T P phi),   theta <- theta + k (y - theta^T phi),   P <- P - k phi^T P.

yhat_t = theta^T phi_{t-1} once p outputs are seen (t >= p); before that yhat_t = y_{t-1} (yhat_0 = 0), as
the authors' baseline (DESIGN.md).
"""

from __future__ import annotations

import torch
from torch import Tensor

from mop.systems.base import Trajectories


def _regressors(y: Tensor, order: int) -> Tensor:
    """phi (B, T, m, p): phi[:, t, i] = [y^i_t, ..., y^i_{t-p+1}], zero before y_0."""
    padded = torch.cat([y.new_zeros(y.shape[0], order - 1, y.shape[2]), y], dim=1)  # (B, T+p-1, m)
    lags = [padded[:, order - 1 - j : padded.shape[1] - j] for j in range(order)]
    return torch.stack(lags, dim=-1)


def rls_predict(y: Tensor, order: int = 2) -> Tensor:
    """One-step RLS-AR(order) predictions yhat (B, T, m) for outputs y (B, T, m)."""
    B, T, m = y.shape
    phi = _regressors(y, order)  # (B, T, m, p)
    theta = y.new_zeros(B, m, order)
    P = torch.eye(order, dtype=y.dtype, device=y.device).repeat(B, m, 1, 1)  # (B, m, p, p)
    preds = [y.new_zeros(B, m)] + [y[:, t - 1] for t in range(1, min(order, T))]
    for t in range(order, T):
        f = phi[:, t - 1]  # (B, m, p), regressor for y_t
        if t > order:
            theta, P = _update(theta, P, phi[:, t - 2], y[:, t - 1])
        preds.append((theta * f).sum(-1))
    return torch.stack(preds, dim=1)


def _update(theta: Tensor, P: Tensor, phi: Tensor, target: Tensor) -> tuple[Tensor, Tensor]:
    """RLS step with the pair (phi (B, m, p), target (B, m))."""
    Pphi = (P @ phi[..., None])[..., 0]  # (B, m, p)
    k = Pphi / (1 + (phi * Pphi).sum(-1, keepdim=True))
    theta = theta + k * (target - (theta * phi).sum(-1))[..., None]
    return theta, P - k[..., None] * Pphi[..., None, :]


def adaptive_order_rls_predict(y: Tensor, max_order: int = 5) -> tuple[Tensor, Tensor]:
    """Run RLS of orders 1..max_order; at each t predict with the order whose summed squared one-step error
    over y_{P+1}..y_{t-1} (P = max_order: the steps where every order predicts by regression, so the startup
    copies do not count) is lowest, per system; ties -> lowest order. Returns yhat (B, T, m), order (B, T)."""
    all_preds = torch.stack([rls_predict(y, p) for p in range(1, max_order + 1)], dim=1)  # (B, P, T, m)
    sq_err = ((all_preds - y[:, None]) ** 2).sum(-1)  # (B, P, T)
    sq_err[:, :, : max_order + 1] = 0  # score only where every order has at least one RLS update
    past = torch.cumsum(sq_err, dim=-1) - sq_err  # (B, P, T): errors strictly before t
    best = past.argmin(dim=1)  # (B, T), argmin returns the first (lowest) order on ties
    yhat = torch.gather(all_preds, 1, best[:, None, :, None].expand(-1, 1, -1, y.shape[2]))[:, 0]
    return yhat, best + 1


class RLSPredictor:
    """RLS autoregression of a fixed order per output dimension (the paper's baseline: order 2)."""

    def __init__(self, order: int = 2, name: str = "rls") -> None:
        self.order, self.name = order, name

    def predict(self, traj: Trajectories) -> Tensor:
        return rls_predict(traj.y.double(), self.order).to(traj.y.dtype)


class AdaptiveOrderRLSPredictor:
    """RLS with the order 1..max_order chosen online by the lowest past one-step error ("rls-best")."""

    def __init__(self, max_order: int = 5, name: str = "rls-best") -> None:
        self.max_order, self.name = max_order, name

    def predict(self, traj: Trajectories) -> Tensor:
        return adaptive_order_rls_predict(traj.y.double(), self.max_order)[0].to(traj.y.dtype)
