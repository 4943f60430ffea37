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

import numpy as np
import torch
from scipy.special import erf
from torch import Tensor

from mop.filters.rls import fixed, initial_state, regressors
from mop.models.attention import rope_angles
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
    """The RLS / ARX feature of the C open windows (slot s % C), in float64 numpy as mop.models.features."""

    def __init__(self, cfg: Any, B: int, like: Tensor) -> None:
        self.p, self.q, self.offset, self.cubes = cfg.rls_order, cfg.arx_order, cfg.rls_offset, cfg.rls_cubes
        self.m, self.k = cfg.output_dim, input_count(cfg)
        self.r = self.p if self.q == 0 else max(self.p, self.q)  # rls_loop's start
        C = cfg.context
        d = (self.p + self.cubes) * self.m + self.q * self.k + int(self.offset)
        prior = feature_prior(cfg)
        theta0, P0 = initial_state(prior, B, d, self.m, like.double())  # (B, d, m), (B, d, d)
        self.theta0, self.P0 = theta0.cpu().numpy(), P0.cpu().numpy()
        # a fixed feature (model.rls_fixed, P_0 = 0): every window predicts with theta_0, nothing to update
        self.fixed = fixed(prior)
        self.theta = None if self.fixed else np.repeat(self.theta0[None], C, axis=0)  # (C, B, d, m)
        self.P = None if self.fixed else np.repeat(self.P0[None], C, axis=0)  # (C, B, d, d)
        self.ys = np.zeros((B, self.p * self.m))  # [y_tau; ..; y_{tau-p+1}]
        self.phi: np.ndarray | None = None  # phi_{tau-1} (B, 1, d)

    def known(self, inputs: Tensor) -> np.ndarray:
        """The regressors known in advance (B, T, q k [+ 1]) float64 of the model inputs (B, T, d_in): the
        input lags [u_tau; ..; u_{tau-q+1}] (zero before the first input) and the constant."""
        u = inputs[..., self.m : self.m + self.k].double()
        parts = [regressors(u, self.q)] if self.q > 0 else []
        parts.append(u.new_ones(*u.shape[:2], int(self.offset)))
        return torch.cat(parts, dim=-1).cpu().numpy()

    def step(
        self, y: np.ndarray, known: np.ndarray, slot: int, fit: np.ndarray, start_up: np.ndarray
    ) -> np.ndarray:
        """Output y_tau (B, m) in the model's units and the known regressors of tau (B, e) -> every window's
        feature (C, B, m) in y's dtype; the window starting at tau is at `slot`; fit (C, 1, 1, 1) float64:
        1 where the window's local position a >= r (it takes the pair), else 0; start_up (C, 1, 1) bool:
        a < r (the feature is y_tau)."""
        dtype, y = y.dtype, y.astype(np.float64)
        self.ys = np.concatenate([y, self.ys[:, : (self.p - 1) * self.m]], axis=-1)
        phi = np.concatenate([self.ys, self.ys[:, : self.cubes * self.m] ** 3, known], axis=-1)[
            :, None
        ]  # (B, 1, d)
        if self.fixed:  # no window takes pairs, so phi need not be kept
            return np.where(start_up, y, (phi @ self.theta0)[:, 0]).astype(dtype)
        self.theta[slot], self.P[slot] = self.theta0, self.P0  # the new window starts afresh
        if self.phi is not None:  # rls_update with the pair (phi_{tau-1}, y_tau), in every fitting window
            old = self.phi
            Pphi = self.P @ old.swapaxes(-1, -2)  # (C, B, d, 1)
            c = fit / (1 + old @ Pphi)  # (C, B, 1, 1); 0 where the window does not fit yet
            self.theta = self.theta + (Pphi * c) * (y[:, None] - old @ self.theta)
            v = Pphi * np.sqrt(c)  # P - c Pphi Pphi^T as P - v v^T: exactly symmetric, as rls_update's P
            self.P = self.P - v * v.swapaxes(-1, -2)
        self.phi = phi
        pred = (phi @ self.theta)[:, :, 0]  # (C, B, m)
        return np.where(start_up, y, pred).astype(dtype)


def _numpy(t: Tensor) -> np.ndarray:
    return t.detach().cpu().numpy()


class _Weights:
    """The model's parameters as numpy arrays, read once (attribute access on modules costs microseconds)."""

    def __init__(self, model: Transformer) -> None:
        def lin(layer: Any) -> tuple[np.ndarray, np.ndarray]:
            return np.ascontiguousarray(_numpy(layer.weight).T), _numpy(layer.bias)

        def ln(layer: Any) -> tuple[np.ndarray, np.ndarray, float]:
            return _numpy(layer.weight), _numpy(layer.bias), float(layer.eps)

        self.read_in = lin(model.read_in)
        self.read_out = lin(model.read_out)
        self.ln_f = ln(model.ln_f)
        self.blocks = [
            (ln(b.ln_1), lin(b.attn.qkv), lin(b.attn.proj), ln(b.ln_2), lin(b.mlp.fc), lin(b.mlp.proj))
            for b in model.blocks
        ]


def _layer_norm(x: np.ndarray, ln: tuple[np.ndarray, np.ndarray, float]) -> np.ndarray:
    w, b, eps = ln
    n = x.shape[-1]
    centred = x - np.add.reduce(x, axis=-1, keepdims=True) / n
    var = np.add.reduce(centred * centred, axis=-1, keepdims=True) / n
    return centred / np.sqrt(var + eps) * w + b


def _gelu(x: np.ndarray) -> np.ndarray:
    """torch's exact GELU, x Phi(x)."""
    return 0.5 * x * (1.0 + erf(x * np.asarray(0.5**0.5, dtype=x.dtype)))


def _rope(x: np.ndarray, cos: np.ndarray, sin: np.ndarray) -> np.ndarray:
    """mop.models.attention.apply_rope on numpy arrays (..., hd)."""
    x1, x2 = x[..., 0::2], x[..., 1::2]
    return np.stack((x1 * cos - x2 * sin, x1 * sin + x2 * cos), axis=-1).reshape(x.shape)


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
    roll-out starts from; y_mean, y_std (m,) float64: the outputs' normalisation (None: none).

    The loop runs on numpy arrays in the model's dtype (the feature's recursion in float64, as
    mop.models.features): its ~50 small operations per step cost a few microseconds each there against
    tens in torch, which made this loop 2-3x slower (`mop bench freerun`)."""
    cfg = model.cfg
    C, H, m = cfg.context, cfg.num_heads, cfg.output_dim
    hd = cfg.width // H
    B, horizon = inputs.shape[0], inputs.shape[1]
    w = _Weights(model)
    X = _numpy(inputs)
    dt = X.dtype
    features = _Features(cfg, B, inputs) if cfg.rls_order > 0 else None
    keys = [np.zeros((C, B, H, C, hd), dt) for _ in model.blocks]
    values = [np.zeros((C, B, H, C, hd), dt) for _ in model.blocks]
    slots = np.arange(C)
    ages = [(phase - slots) % C for phase in range(C)]  # at tau = phase mod C: slot j's local position a_j
    # the keys and values of input tau are kept at buffer position tau % C (the phase), so at phase
    # position b holds input tau - ((phase - b) % C), which window slot j (started at tau - a_j) reads
    # where (phase - b) % C <= a_j; attention does not depend on the order of the keys
    hidden = [((phase - slots[None]) % C > a[:, None])[:, None, None, None] for phase, a in enumerate(ages)]
    known = None if features is None else features.known(inputs)  # (B, T, e)
    if features is not None:
        fits = [(a >= features.r).astype(np.float64)[:, None, None, None] for a in ages]
        start_ups = [(a < features.r)[:, None, None] for a in ages]
    if model.wpe is not None:
        table = _numpy(model.wpe.weight)
        embeds = [table[a][:, None] for a in ages]  # (C, 1, d)
    else:
        ropes = [
            tuple(_numpy(c)[:, None, None].astype(dt) for c in rope_angles(torch.as_tensor(a), hd))
            for a in ages
        ]  # (C, 1, 1, hd/2) each
    scale = np.asarray(hd**-0.5, dtype=dt)
    mean = None if y_mean is None else _numpy(y_mean).astype(np.float64)
    std = None if y_std is None else _numpy(y_std).astype(np.float64)
    out: list[np.ndarray] = []
    pred = _numpy(first).astype(np.float64)
    begin = max(0, context + 1 - C)  # the first window any prediction reads: s(c + 1)
    last = len(model.blocks) - 1
    (w_in, b_in), (w_out, b_out) = w.read_in, w.read_out
    plain_mean = cfg.readout == "mean" and cfg.horizons == 1
    for tau in range(begin, horizon):
        x = X[:, tau]  # (B, d_in)
        if tau >= context:  # the fed-back output in the model's units
            y = pred if mean is None else (pred - mean) / std
            x = np.concatenate([y.astype(dt), x[:, m:]], axis=-1)
        slot = tau % C
        h = x @ w_in[: x.shape[-1]] + b_in  # (B, d): the read-in of the input every window shares
        r = None
        if features is not None:  # plus each window's own feature's
            r = features.step(x[:, :m], known[:, tau], slot, fits[slot], start_ups[slot])
            h = h + r @ w_in[x.shape[-1] :]  # (C, B, d)
        else:
            h = np.repeat(h[None], C, axis=0)
        rope = None
        if model.wpe is not None:
            h = h + embeds[slot]
        else:
            rope = ropes[slot]
        read = max(0, tau + 1 - C) % C  # the slot of the window of step L = tau + 1
        for layer, (ln_1, (w_qkv, b_qkv), (w_proj, b_proj), ln_2, (w_fc, b_fc), (w_p2, b_p2)) in enumerate(
            w.blocks
        ):
            qkv = (_layer_norm(h, ln_1) @ w_qkv + b_qkv).reshape(h.shape[0], B, 3, H, hd)
            q, k, v = qkv[:, :, 0], qkv[:, :, 1], qkv[:, :, 2]  # each (C, B, H, hd)
            if rope is not None:  # window slot j at its position a_j
                q, k = _rope(q, *rope), _rope(k, *rope)
            keys[layer][:, :, :, slot] = k
            values[layer][:, :, :, slot] = v
            rows = slice(None)  # the windows whose outputs are read on
            mask = hidden[slot]
            if layer == last:  # only the read window's: its keys and values are all the others need
                if tau < context:
                    break
                rows = slice(read, read + 1)
                h, q, mask = h[rows], q[rows], mask[rows]
            scores = (q[..., None, :] @ keys[layer][rows].swapaxes(-1, -2)) * scale  # (C or 1, B, H, 1, C)
            scores = np.where(mask, -np.inf, scores)
            e = np.exp(scores - scores.max(-1, keepdims=True))
            att = ((e / e.sum(-1, keepdims=True)) @ values[layer][rows])[..., 0, :]  # (C or 1, B, H, hd)
            h = h + att.reshape(h.shape[0], B, H * hd) @ w_proj + b_proj
            h = h + _gelu(_layer_norm(h, ln_2) @ w_fc + b_fc) @ w_p2 + b_p2
        if tau < context:
            continue
        raw = _layer_norm(h[0], w.ln_f) @ w_out + b_out  # (B, horizon_dim)
        if plain_mean:  # split_horizons' one-step mean: the read-out's first m, in float32 as there
            mu = raw[:, :m].astype(np.float32).astype(np.float64)
        else:
            mu = _numpy(split_horizons(torch.from_numpy(raw), cfg)[0]).astype(np.float64)  # (B, m)
        if r is not None:
            mu = mu + r[read]
        pred = mu if mean is None else mu * std + mean
        out.append(pred)
    return [torch.from_numpy(p) for p in out]
