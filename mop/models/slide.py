"""The sliding-window free run of a transformer at the cost of one new input per window and step.

mop.models.simulate's "window" path predicts y_{L} (L = c+1..T) from one forward on the last C inputs of
hist = z_0..z_{L-1} (window start s(L) = max(0, L - C), positions 0..C-1 of the window), every window's input
features (the RLS / ARX feature, mop.models.features) restarted at its first input. A forward per step
costs the RLS recursion over C inputs and the network over C inputs, ~2.5 ms for a 1 x 32 model with
C = 50 (about 100 s on a 40,000-step record).

sliding_rollout computes the same numbers incrementally. Window s sees the inputs z_s, z_{s+1}, .. in order,
causally, so each window is a growing sequence whose state is kept from step to step:
- the C windows that are open at input tau (s = tau-C+1..tau, slot s % C, local position a = tau - s) each
  read z_tau once: its RLS / ARX fit (theta, P) per window takes the pair (phi_{tau-1}, y_tau) where a >= r
  = max(p, q) (rls_loop's start), so every update is one batched rls_update over the windows, and the
  window's feature at position a is y_tau for a < r, else theta^T phi_tau. Their regressors phi are the
  record's: the lags of a window past its start-up (a >= r >= p, q) never reach before its first input;
- the network reads the new input of every window at its own position a (learned embedding or RoPE) and
  writes its keys and values into the window's key / value buffer at position a; the window's output at a
  attends to its positions 0..a (the causal forward of the window's inputs so far);
- the output wanted at step L is window s(L)'s at its last position a = L - 1 - s(L).
So each step costs one batched token per open window (C tokens) and the RLS update of C small fits,
in ~40 tensor operations, against a whole window's recomputation. Equal to the window path to float
rounding (tests/test_slide.py: float64 models, 1e-9).

It serves the models that slide_fast accepts: the transformer of mop.models.transformer reading no feature
or the RLS / ARX feature alone (no running scale, record normalisation, residual scale, mixture prior,
observation mask); others take the window path.
"""

from __future__ import annotations

from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor

from mop.filters.rls import initial_state, rls_update
from mop.models.attention import apply_rope, rope_angles
from mop.models.features import feature_prior, input_count
from mop.models.horizons import split_horizons
from mop.models.transformer import Transformer


def slide_fast(model: Any) -> bool:
    """Whether sliding_rollout serves `model` (see the module docstring)."""
    if not isinstance(model, Transformer):
        return False
    cfg = model.cfg
    return (
        cfg.input_scale == "none"
        and cfg.record_norm == "none"
        and cfg.residual_scale == "none"
        and cfg.rls_prior_weights is None
        and not cfg.observation_mask
    )


class _Features:
    """The RLS / ARX feature of the C open windows (slot s % C), in float64 as mop.models.features."""

    def __init__(self, cfg: Any, B: int, like: Tensor) -> None:
        self.p, self.q, self.offset = cfg.rls_order, cfg.arx_order, cfg.rls_offset
        self.m, self.k = cfg.output_dim, input_count(cfg)
        self.r = self.p if self.q == 0 else max(self.p, self.q)  # rls_loop's start
        C = cfg.context
        d = self.p * self.m + self.q * self.k + int(self.offset)
        theta0, P0 = initial_state(feature_prior(cfg), B, d, self.m, like.double())  # (B, d, m), (B, d, d)
        self.theta0, self.P0 = theta0, P0
        self.theta = theta0.repeat(C, 1, 1, 1)  # (C, B, d, m)
        self.P = P0.repeat(C, 1, 1, 1)  # (C, B, d, d)
        self.ys = like.new_zeros(B, self.p, self.m, dtype=torch.float64)  # y_tau..y_{tau-p+1}
        self.us = like.new_zeros(B, max(self.q, 1), self.k, dtype=torch.float64)  # u_tau..u_{tau-q+1}
        self.phi: Tensor | None = None  # phi_{tau-1} (B, d)

    def step(self, z: Tensor, slot: int, age: Tensor) -> Tensor:
        """Input z_tau (B, d_in) in the model's units -> every window's feature (C, B, m) in z's dtype; the
        window starting at tau is at `slot`, age (C,) the windows' local positions a."""
        y = z[:, : self.m].double()
        self.ys = torch.cat([y[:, None], self.ys[:, :-1]], dim=1)
        parts = [self.ys.flatten(1)]
        if self.q > 0:
            self.us = torch.cat([z[:, None, self.m : self.m + self.k].double(), self.us[:, :-1]], dim=1)
            parts.append(self.us[:, : self.q].flatten(1))
        if self.offset:
            parts.append(y.new_ones(y.shape[0], 1))
        phi = torch.cat(parts, dim=-1)  # (B, d)
        self.theta[slot], self.P[slot] = self.theta0, self.P0  # the new window starts afresh
        if self.phi is not None:  # the pair (phi_{tau-1}, y_tau) for the windows with a >= r
            C, B, d, m = self.theta.shape
            theta, P = rls_update(
                self.theta.view(C * B, d, m),
                self.P.view(C * B, d, d),
                self.phi.repeat(C, 1),
                y.repeat(C, 1),
            )
            fit = (age >= self.r)[:, None, None, None]
            self.theta = torch.where(fit, theta.view(C, B, d, m), self.theta)
            self.P = torch.where(fit, P.view(C, B, d, d), self.P)
        self.phi = phi
        pred = (self.theta.mT @ phi[:, :, None])[..., 0]  # (C, B, m)
        return torch.where((age < self.r)[:, None, None], y, pred).to(z.dtype)


@torch.no_grad()
def sliding_rollout(
    model: Transformer,
    z: Tensor,
    u: Tensor | None,
    first: Tensor,
    context: int,
    horizon: int,
    to_model: Any,
    to_data: Any,
) -> list[Tensor]:
    """The window path's predictions of y_{c+1}..y_T (c = context, T = horizon), each (B, m) from
    to_data, for the model in eval mode.

    z (B, c, m + k): the measured inputs z_0..z_{c-1} in data units; u (B, T+1, k)|None the given inputs;
    first (B, m): the prediction of y_c the roll-out starts from (data units); to_model maps data-unit
    inputs (B, 1, m + k) to the model's (B, 1, d_in), to_data model-unit means (B, m) to data units."""
    cfg = model.cfg
    C, L, H = cfg.context, cfg.num_layers, cfg.num_heads
    hd = cfg.width // H
    B = z.shape[0]
    p = next(model.parameters())
    features = _Features(cfg, B, p) if cfg.rls_order > 0 else None
    keys = [p.new_zeros(C, B, H, C, hd) for _ in range(L)]
    values = [p.new_zeros(C, B, H, C, hd) for _ in range(L)]
    slots = torch.arange(C, device=p.device)
    positions = torch.arange(C, device=p.device)
    out: list[Tensor] = []
    pred = first
    begin = max(0, context + 1 - C)  # the first window any prediction reads: s(c + 1)
    for tau in range(begin, horizon):
        if tau < context:
            x = to_model(z[:, tau : tau + 1])[:, 0]  # (B, d_in) a measured input
        else:
            fed = pred if u is None else torch.cat([pred, u[:, tau]], dim=-1)
            x = to_model(fed[:, None])[:, 0]
        slot = tau % C
        age = (tau - slots) % C  # (C,): window in slot j started at tau - age_j
        net = x.expand(C, B, x.shape[-1])
        r = None if features is None else features.step(x, slot, age)
        if r is not None:
            net = torch.cat([net, r], dim=-1)  # (C, B, d_in + m)
        h = model.read_in(net)  # (C, B, d)
        rope = None
        if model.wpe is not None:
            h = h + model.wpe.weight[age][:, None]
        else:
            cos, sin = rope_angles(age, hd)  # (C, hd/2)
            rope = cos[:, None, None, None], sin[:, None, None, None]
        mask = (positions[None] <= age[:, None])[:, None, None, None]  # (C, 1, 1, 1, C) positions 0..a
        for layer, block in enumerate(model.blocks):
            a = block.ln_1(h)
            q, k, v = block.attn.qkv(a).view(C, B, 3, H, 1, hd).unbind(2)  # each (C, B, H, 1, hd)
            if rope is not None:
                q, k = apply_rope(q, *rope), apply_rope(k, *rope)
            keys[layer][slots, :, :, age] = k[:, :, :, 0]
            values[layer][slots, :, :, age] = v[:, :, :, 0]
            att = F.scaled_dot_product_attention(q, keys[layer], values[layer], attn_mask=mask)
            h = h + block.attn.proj(att.reshape(C, B, H * hd))
            h = h + block.mlp(block.ln_2(h))
        if tau < context:
            continue
        s = max(0, tau + 1 - C)  # the window of step L = tau + 1
        mu = split_horizons(model.read_out(model.ln_f(h[s % C])), cfg)[0]  # (B, m)
        if r is not None:
            mu = mu + r[s % C]
        pred = to_data(mu)
        out.append(pred)
    return out
