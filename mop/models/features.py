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
    for p = 2); with model.arx_order = q > 0 the ARX(p, q) prediction from y_0..y_t and u_0..u_t
    (mop.filters.arx: the regressors also hold u_t..u_{t-q+1}, for systems driven by inputs); fed in as m
    extra channels (divided by s_t with the running scale), and the read-out predicts the residual:
    yhat_{t+1} = r_{t+1} + s_t out_t. At initialisation (small read-out weights) the model is
    the RLS predictor, so training starts from it rather than from zero.
    model.rls_offset = true adds a constant regressor (mop.filters.arx's offset, an intercept), for outputs
    with an offset such as the sysid benchmarks' per-sequence mean removal.

In a sliding window (trajectories longer than model.context, LearnedPredictor mode "window") both features
restart with each window, exactly as the network's attention does. Streaming (FeatureState) keeps them over
the whole stream: equal to the forward inside the context, beyond it the running sums and the RLS fit cover
every step so far (the KV cache is the rolling approximation documented in mop.models.transformer anyway).
"""

from __future__ import annotations

import torch
from torch import Tensor

from mop.config import ModelConfig
from mop.errors import MopError
from mop.filters.arx import arx_predict
from mop.filters.rls import regressors, rls_predict, rls_update

SCALE_EPS = 1e-4  # floor of s_t^2: a trajectory of zeros gets s = 0.01, not a division by zero


def extra_input_dim(cfg: ModelConfig) -> int:
    """Channels added to the model's input: 1 (log s_t) with the running scale, m with the RLS feature."""
    return (1 if cfg.input_scale == "running" else 0) + (cfg.output_dim if cfg.rls_order > 0 else 0)


def running_scale(y: Tensor) -> Tensor:
    """s_t = sqrt(eps + mean_{tau <= t} ||y_tau||^2 / m): y (B, T, m) -> (B, T, 1)."""
    count = torch.arange(1, y.shape[1] + 1, device=y.device, dtype=y.dtype)[None, :, None]  # (1, T, 1)
    mean_sq = (y**2).mean(-1, keepdim=True).cumsum(1) / count  # (B, T, 1)
    return (mean_sq + SCALE_EPS).sqrt()


def input_count(cfg: ModelConfig) -> int:
    """k, the number of inputs u in the model's input layout [y, u] (+ the mask's m channels)."""
    return cfg.input_dim - cfg.output_dim * (2 if cfg.observation_mask else 1)


def check_features(cfg: ModelConfig) -> None:
    """One-line errors for feature options the model's inputs cannot serve."""
    if cfg.arx_order > 0 and input_count(cfg) <= 0:
        raise MopError("model.arx_order reads input lags, but the model has no inputs u; use rls_order alone")


def rls_next(
    y: Tensor, order: int, u: Tensor | None = None, input_order: int = 0, offset: bool = False
) -> Tensor:
    """r (B, T, m): r[:, t] is the RLS-AR(order) prediction of y_{t+1} from y_0..y_t, for y (B, T, m); with
    u (B, T, k) and input_order q > 0 the ARX(order, q) prediction from y_0..y_t and u_0..u_t; offset: with
    a constant regressor."""
    pad = lambda a: torch.cat([a, a.new_zeros(a.shape[0], 1, a.shape[2])], dim=1).double()  # noqa: E731
    if input_order > 0 or offset:  # the pad rows are never read
        u_lags = pad(u) if input_order > 0 else None
        return arx_predict(pad(y), u_lags, order, max(input_order, 1), offset)[:, 1:].to(y.dtype)
    return rls_predict(pad(y), order)[:, 1:].to(y.dtype)  # (B, T, m)


def augment(inputs: Tensor, cfg: ModelConfig) -> tuple[Tensor, Tensor | None, Tensor | None]:
    """inputs (B, T, d_in) -> (network inputs (B, T, d_in + extra), scale s (B, T, 1)|None, base r|None)."""
    m = cfg.output_dim
    y = inputs[..., :m]  # (B, T, m)
    scale = running_scale(y) if cfg.input_scale == "running" else None
    k = input_count(cfg)
    u = inputs[..., m : m + k] if cfg.arx_order > 0 else None
    base = rls_next(y, cfg.rls_order, u, cfg.arx_order, cfg.rls_offset) if cfg.rls_order > 0 else None
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
        p, q, self.k = cfg.rls_order, cfg.arx_order, input_count(cfg)
        d = p * cfg.output_dim + q * self.k + (1 if cfg.rls_offset else 0)
        if p > 0:
            f64 = dict(device=device, dtype=torch.float64)
            self.theta = torch.zeros(batch_size, d, self.m, **f64)
            self.P = torch.eye(d, **f64).repeat(batch_size, 1, 1)
            self.recent = torch.zeros(batch_size, p + 1, self.m, **f64)
            self.recent_u = torch.zeros(batch_size, q + 1, self.k if q > 0 else 0, **f64)

    def step(self, z: Tensor) -> tuple[Tensor, Tensor | None, Tensor | None]:
        """z_t (B, d_in) -> network input (B, 1, d_in + extra), s_t (B, 1, 1)|None, r_{t+1} (B, 1, m)|None."""
        y = z[:, : self.m]
        scale = base = None
        if self.cfg.input_scale == "running":
            self.sum_sq = self.sum_sq + (y**2).mean(-1, keepdim=True)
            scale = (self.sum_sq / (self.t + 1) + SCALE_EPS).sqrt()[:, None]  # (B, 1, 1)
        if self.cfg.rls_order > 0:
            u = z[:, self.m : self.m + self.k] if self.cfg.arx_order > 0 else z[:, :0]
            base = self._rls_step(y.double(), u.double()).to(z.dtype)[:, None]  # (B, 1, m)
        self.t += 1
        return _assemble(z[:, None], scale, base, self.m), scale, base

    def _rls_step(self, y: Tensor, u: Tensor) -> Tensor:
        """As rls_predict (arx_predict with q = arx_order > 0): fit the pair (phi_{t-1}, y_t) once t >= r =
        max(p, q), then predict y_{t+1} (y_t for t < r); u (B, k) is u_t (B, 0 without input lags)."""
        p, q, t = self.cfg.rls_order, self.cfg.arx_order, self.t
        r = max(p, q)
        self.recent = torch.cat([self.recent[:, 1:], y[:, None]], dim=1)  # (B, p+1, m): y_{t-p}..y_t
        self.recent_u = torch.cat([self.recent_u[:, 1:], u[:, None]], dim=1)  # (B, q+1, k): u_{t-q}..u_t
        if t >= r:
            self.theta, self.P = rls_update(self.theta, self.P, self._phi(p, q, 0), y)
        if t < r:
            return y
        return (self.theta.mT @ self._phi(p, q, 1)[..., None])[..., 0]

    def _phi(self, p: int, q: int, last: int) -> Tensor:
        """(B, p m + q k [+ 1]): [y_s; ...; y_{s-p+1}; u_s; ...; u_{s-q+1} (; 1 with rls_offset)] for
        s = t - 1 (last = 0) or t (1)."""
        parts = [regressors(self.recent[:, last : p + last], p)[:, -1]]
        if q > 0:
            parts.append(regressors(self.recent_u[:, last : q + last], q)[:, -1])
        if self.cfg.rls_offset:
            parts.append(parts[0].new_ones(parts[0].shape[0], 1))
        return torch.cat(parts, dim=-1) if len(parts) > 1 else parts[0]
