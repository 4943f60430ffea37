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
  writes its keys and values into the window's key / value buffer (at tau % C); the window's output at a
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

from mop.filters.rls import initial_state, regressors
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
        self.ys = like.new_zeros(B, self.p * self.m, dtype=torch.float64)  # [y_tau; ..; y_{tau-p+1}]
        self.phi: Tensor | None = None  # phi_{tau-1} (B, 1, d)

    def known(self, inputs: Tensor) -> Tensor:
        """The regressors known in advance (B, T, q k [+ 1]) float64 of the model inputs (B, T, d_in): the
        input lags [u_tau; ..; u_{tau-q+1}] (zero before the first input) and the constant."""
        u = inputs[..., self.m : self.m + self.k].double()
        parts = [regressors(u, self.q)] if self.q > 0 else []
        parts.append(u.new_ones(*u.shape[:2], int(self.offset)))
        return torch.cat(parts, dim=-1)

    def step(self, y: Tensor, known: Tensor, slot: int, fit: Tensor, start_up: Tensor) -> Tensor:
        """Output y_tau (B, m) in the model's units and the known regressors of tau (B, e) -> every window's
        feature (C, B, m) in y's dtype; the window starting at tau is at `slot`; fit (C, 1, 1, 1) float64:
        1 where the window's local position a >= r (it takes the pair), else 0; start_up (C, 1, 1) bool:
        a < r (the feature is y_tau)."""
        dtype, y = y.dtype, y.double()
        self.ys = torch.cat([y, self.ys[:, : (self.p - 1) * self.m]], dim=-1)
        phi = torch.cat([self.ys, known], dim=-1)[:, None]  # (B, 1, d)
        self.theta[slot], self.P[slot] = self.theta0, self.P0  # the new window starts afresh
        if self.phi is not None:  # rls_update with the pair (phi_{tau-1}, y_tau), in every fitting window
            old = self.phi
            Pphi = self.P @ old.mT  # (C, B, d, 1)
            c = fit / (1 + old @ Pphi)  # (C, B, 1, 1); 0 where the window does not fit yet
            self.theta = torch.addcmul(self.theta, Pphi * c, y[:, None] - old @ self.theta)
            v = Pphi * c.sqrt()  # P - c Pphi Pphi^T as P - v v^T: exactly symmetric, as rls_update's P
            self.P = torch.addcmul(self.P, v, v.mT, value=-1)
        self.phi = phi
        pred = (phi @ self.theta)[:, :, 0]  # (C, B, m)
        return torch.where(start_up, y, pred).to(dtype)


@torch.no_grad()
def sliding_rollout(
    model: Transformer,
    inputs: Tensor,
    first: Tensor,
    context: int,
    y_mean: Tensor | None = None,
    y_std: Tensor | None = None,
) -> list[Tensor]:
    """The window path's predictions of y_{c+1}..y_T (c = context), each (B, m) float64 in data units, for
    the model in eval mode.

    inputs (B, T, d_in): the model's inputs z_0..z_{T-1} in its units and dtype, of which the outputs
    from y_c on are replaced by the roll-out's own; first (B, m): the prediction of y_c in data units the
    roll-out starts from; y_mean, y_std (m,) float64: the outputs' normalisation (None: none)."""
    cfg = model.cfg
    C, H, m = cfg.context, cfg.num_heads, cfg.output_dim
    hd = cfg.width // H
    B, horizon = inputs.shape[0], inputs.shape[1]
    like = inputs
    features = _Features(cfg, B, like) if cfg.rls_order > 0 else None
    keys = [like.new_zeros(C, B, H, C, hd) for _ in model.blocks]
    values = [like.new_zeros(C, B, H, C, hd) for _ in model.blocks]
    slots = torch.arange(C, device=like.device)
    positions = torch.arange(C, device=like.device)
    ages = [(phase - slots) % C for phase in range(C)]  # at tau = phase mod C: slot j's local position a_j
    # the keys and values of input tau are kept at buffer position tau % C (the phase), so at phase
    # position b holds input tau - ((phase - b) % C), which window slot j (started at tau - a_j) reads
    # where (phase - b) % C <= a_j; attention does not depend on the order of the keys
    hidden = [
        ((phase - positions[None]) % C > a[:, None])[:, None, None, None] for phase, a in enumerate(ages)
    ]
    known = None if features is None else features.known(inputs)  # (B, T, e)
    if features is not None:
        fits = [(a >= features.r).double()[:, None, None, None] for a in ages]
        start_ups = [(a < features.r)[:, None, None] for a in ages]
    if model.wpe is not None:
        embeds = [model.wpe.weight[a][:, None] for a in ages]  # (C, 1, d)
    else:
        ropes = [tuple(c[:, None, None] for c in rope_angles(a, hd)) for a in ages]  # (C, 1, 1, hd/2) each
    scale = hd**-0.5
    out: list[Tensor] = []
    pred = first
    begin = max(0, context + 1 - C)  # the first window any prediction reads: s(c + 1)
    for tau in range(begin, horizon):
        x = inputs[:, tau]  # (B, d_in)
        if tau >= context:  # the fed-back output in the model's units
            y = pred if y_mean is None else (pred - y_mean) / y_std
            x = torch.cat([y.to(x.dtype), x[:, m:]], dim=-1)
        slot = tau % C
        net = x.expand(C, B, x.shape[-1])
        r = None
        if features is not None:
            r = features.step(x[:, :m], known[:, tau], slot, fits[slot], start_ups[slot])
            net = torch.cat([net, r], dim=-1)  # (C, B, d_in + m)
        h = F.linear(net, model.read_in.weight, model.read_in.bias)  # (C, B, d)
        rope = None
        if model.wpe is not None:
            h = h + embeds[slot]
        else:
            rope = ropes[slot]
        read = max(0, tau + 1 - C) % C  # the slot of the window of step L = tau + 1
        last = len(model.blocks) - 1
        for layer, block in enumerate(model.blocks):
            attn = block.attn
            qkv = F.linear(_layer_norm(h, block.ln_1), attn.qkv.weight, attn.qkv.bias)
            q, k, v = qkv.view(h.shape[0], B, 3, H, hd).unbind(2)  # each (C, B, H, hd)
            if rope is not None:  # window slot j at its position a_j
                q, k = apply_rope(q, *rope), apply_rope(k, *rope)
            keys[layer][:, :, :, slot] = k
            values[layer][:, :, :, slot] = v
            rows = slice(None)  # the windows whose outputs are read on
            if layer == last:  # only the read window's: its keys and values are all the others need
                if tau < context:
                    break
                rows = slice(read, read + 1)
                h, q = h[rows], q[rows]
            scores = (q[..., None, :] @ keys[layer][rows].mT) * scale  # (C or 1, B, H, 1, C)
            w = scores.masked_fill(hidden[slot][rows], float("-inf")).softmax(-1)
            att = (w @ values[layer][rows])[..., 0, :]  # (C or 1, B, H, hd)
            h = h + F.linear(att.reshape(h.shape[0], B, H * hd), attn.proj.weight, attn.proj.bias)
            mlp = block.mlp
            g = F.gelu(F.linear(_layer_norm(h, block.ln_2), mlp.fc.weight, mlp.fc.bias))
            h = h + F.linear(g, mlp.proj.weight, mlp.proj.bias)
        if tau < context:
            continue
        mu = split_horizons(model.read_out(_layer_norm(h[0], model.ln_f)), cfg)[0]  # (B, m)
        if r is not None:
            mu = mu + r[read]
        pred = mu.double() if y_mean is None else mu.double() * y_std + y_mean
        out.append(pred)
    return out


def _layer_norm(x: Tensor, ln: Any) -> Tensor:
    return F.layer_norm(x, ln.normalized_shape, ln.weight, ln.bias, ln.eps)
