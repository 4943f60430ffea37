"""Causal input features of the learned models: a running output scale and an RLS one-step prediction.

Both are options of ModelConfig (off by default, so the paper's model is unchanged) and are computed inside
the model from its inputs z_t = [y_t, u_t] (B, T, d_in), the first m channels being y_t; position t sees
z_0..z_t only, so the model stays causal and LearnedPredictor needs nothing new.

model.input_scale = "running" (causal per-trajectory normalisation):
    s_t = sqrt(eps + (1 / (t+1)) sum_{tau <= t} ||y_tau||^2 / m)          (B, T, 1), eps = SCALE_EPS
    the model reads [y_t / s_t, u_t, log s_t] and its mean read-out is multiplied back: yhat_{t+1} = s_t out_t
    (a Gaussian read-out's variance by s_t^2). Systems whose outputs differ in size by orders of magnitude
    (upper-triangular A: the per-system RMS of y spans a factor of 44) then look alike to the network.
model.rls_order = p > 0 (the RLS feature):
    r_{t+1} = the matrix RLS-AR(p) prediction of y_{t+1} from y_0..y_t (mop.filters.rls, the paper's baseline
    for p = 2), fed in as m extra channels (divided by s_t with the running scale), and the read-out predicts
    the residual: yhat_{t+1} = r_{t+1} + s_t out_t. At initialisation (small read-out weights) the model is
    the RLS predictor, so training starts from it rather than from zero.
model.rls_inputs = true (with rls_order = p): the feature is ARX(p, p) instead (mop.filters.arx), regressing
    y_{t+1} on [y_t..y_{t-p+1}, u_t..u_{t-p+1}] where u_t are the model's input channels after y_t (the
    observation mask, if any, excluded); for systems driven by inputs, where output-only RLS is no better than
    the last value. model.rls_offset = true adds a constant regressor (arx's offset), for outputs with an
    offset such as the sysid benchmarks' per-sequence mean removal.

In a sliding window (trajectories longer than model.context, LearnedPredictor mode "window") both features
restart with each window, exactly as the network's attention does. Streaming (FeatureState) keeps them over
the whole stream: equal to the forward inside the context, beyond it the running sums and the RLS fit cover
every step so far (the KV cache is the rolling approximation documented in mop.models.transformer anyway).
"""

from __future__ import annotations

import torch
from torch import Tensor

from mop.config import ModelConfig
from mop.filters.arx import arx_predict, arx_regressors
from mop.filters.rls import rls_update

SCALE_EPS = 1e-4  # floor of s_t^2: a trajectory of zeros gets s = 0.01, not a division by zero


def extra_input_dim(cfg: ModelConfig) -> int:
    """Channels added to the model's input: 1 (log s_t) with the running scale, m with the RLS feature."""
    return (1 if cfg.input_scale == "running" else 0) + (cfg.output_dim if cfg.rls_order > 0 else 0)


def running_scale(y: Tensor) -> Tensor:
    """s_t = sqrt(eps + mean_{tau <= t} ||y_tau||^2 / m): y (B, T, m) -> (B, T, 1)."""
    count = torch.arange(1, y.shape[1] + 1, device=y.device, dtype=y.dtype)[None, :, None]  # (1, T, 1)
    mean_sq = (y**2).mean(-1, keepdim=True).cumsum(1) / count  # (B, T, 1)
    return (mean_sq + SCALE_EPS).sqrt()


def _pad(x: Tensor) -> Tensor:
    return torch.cat([x, x.new_zeros(x.shape[0], 1, x.shape[2])], dim=1).double()  # the pad is never read


def rls_next(y: Tensor, order: int, u: Tensor | None = None, offset: bool = False) -> Tensor:
    """r (B, T, m): r[:, t] is the RLS-AR(order) prediction of y_{t+1} from y_0..y_t, for y (B, T, m); with
    inputs u (B, T, k) and/or offset, the ARX(order, order) prediction from y_0..y_t and u_0..u_t."""
    padded_u = None if u is None else _pad(u)
    return arx_predict(_pad(y), padded_u, order, order, offset)[:, 1:].to(y.dtype)  # (B, T, m)


def feature_inputs(inputs: Tensor, cfg: ModelConfig) -> Tensor | None:
    """The input channels u (B, T, k) the ARX feature regresses on (rls_inputs), else None: the channels
    after the m outputs, less the observation mask's m channels where the model has them."""
    if not cfg.rls_inputs:
        return None
    m = cfg.output_dim
    stop = inputs.shape[-1] - (m if cfg.observation_mask else 0)
    return inputs[..., m:stop] if stop > m else None


def augment(inputs: Tensor, cfg: ModelConfig) -> tuple[Tensor, Tensor | None, Tensor | None]:
    """inputs (B, T, d_in) -> (network inputs (B, T, d_in + extra), scale s (B, T, 1)|None, base r|None)."""
    m = cfg.output_dim
    y = inputs[..., :m]  # (B, T, m)
    scale = running_scale(y) if cfg.input_scale == "running" else None
    base = None
    if cfg.rls_order > 0:
        base = rls_next(y, cfg.rls_order, feature_inputs(inputs, cfg), cfg.rls_offset)
    return _assemble(inputs, scale, base, m), scale, base


def _assemble(inputs: Tensor, scale: Tensor | None, base: Tensor | None, m: int) -> Tensor:
    """[y / s, u, log s, r / s] (the parts that are on) along the last axis."""
    parts = [inputs]
    if scale is not None:
        parts = [inputs[..., :m] / scale, inputs[..., m:], scale.log()]
    if base is not None:
        parts.append(base if scale is None else base / scale)
    return parts[0] if len(parts) == 1 else torch.cat(parts, dim=-1)


def restore(
    mu: Tensor, var: Tensor | None, scale: Tensor | None, base: Tensor | None
) -> tuple[Tensor, Tensor | None]:
    """Network mean/variance (B, T, m) -> predictions in the data's units: s mu + r and s^2 var."""
    if scale is not None:
        mu = mu * scale
        var = None if var is None else var * scale**2
    if base is not None:
        mu = mu + base
    return mu, var


class FeatureState:
    """The features one input at a time (streaming): running sums and the RLS fit (theta, P) per system."""

    def __init__(self, cfg: ModelConfig, batch_size: int, device: torch.device, dtype: torch.dtype) -> None:
        self.cfg, self.m, self.t = cfg, cfg.output_dim, 0
        self.sum_sq = torch.zeros(batch_size, 1, device=device, dtype=dtype)
        p = cfg.rls_order
        if p > 0:
            k = cfg.input_dim - self.m - (self.m if cfg.observation_mask else 0) if cfg.rls_inputs else 0
            self.k = k
            d = p * (self.m + k) + (1 if cfg.rls_offset else 0)
            self.theta = torch.zeros(batch_size, d, self.m, device=device, dtype=torch.float64)
            self.P = torch.eye(d, device=device, dtype=torch.float64).repeat(batch_size, 1, 1)
            self.recent = torch.zeros(batch_size, p + 1, self.m + k, device=device, dtype=torch.float64)

    def step(self, z: Tensor) -> tuple[Tensor, Tensor | None, Tensor | None]:
        """z_t (B, d_in) -> network input (B, 1, d_in + extra), s_t (B, 1, 1)|None, r_{t+1} (B, 1, m)|None."""
        y = z[:, : self.m]
        scale = base = None
        if self.cfg.input_scale == "running":
            self.sum_sq = self.sum_sq + (y**2).mean(-1, keepdim=True)
            scale = (self.sum_sq / (self.t + 1) + SCALE_EPS).sqrt()[:, None]  # (B, 1, 1)
        if self.cfg.rls_order > 0:
            yu = z[:, : self.m + self.k].double()  # (B, m + k): y_t and the regressed inputs u_t
            base = self._rls_step(yu).to(z.dtype)[:, None]  # (B, 1, m)
        self.t += 1
        return _assemble(z[:, None], scale, base, self.m), scale, base

    def _phi(self, recent: Tensor) -> Tensor:
        """phi (B, d) of the newest row of recent (B, p, m + k): arx_regressors' [y lags, u lags(, 1)]."""
        p, u = self.cfg.rls_order, recent[..., self.m :] if self.k else None
        return arx_regressors(recent[..., : self.m], u, p, p, self.cfg.rls_offset)[:, -1]

    def _rls_step(self, yu: Tensor) -> Tensor:
        """As rls_next: fit the pair (phi_{t-1}, y_t) once t >= p, then predict y_{t+1} (y_t for t < p).
        yu (B, m + k): y_t and the regressed inputs u_t."""
        p, t, y = self.cfg.rls_order, self.t, yu[:, : self.m]
        self.recent = torch.cat([self.recent[:, 1:], yu[:, None]], dim=1)  # (B, p+1, m+k): rows t-p..t
        if t >= p:
            self.theta, self.P = rls_update(self.theta, self.P, self._phi(self.recent[:, :-1]), y)
        if t < p:
            return y
        return (self.theta.mT @ self._phi(self.recent[:, 1:])[..., None])[..., 0]
