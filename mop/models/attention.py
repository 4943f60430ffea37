"""Causal self-attention of the transformer (mop.models.transformer) with rotary positions, in its three uses.

    forward / prefill   x (B, T, d): position t attends to 0..t (prefill also returns the keys and values,
                        and can continue a window from key / value buffers)
    branch              many branches per group continue from shared keys and values (mop.models.rollout)
    step                one new input against a circular key / value cache (streaming)

Attention of query q_i over keys k_j: softmax_j(q_i . k_j / sqrt(hd)) weighting v_j, per head (H heads of
width hd = d / H). With position = "rope", q and k are rotated by their positions (rope_angles, apply_rope),
so scores depend on relative distances only.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from mop.config import ModelConfig


def rope_angles(positions: Tensor, head_dim: int, base: float = 10000.0) -> tuple[Tensor, Tensor]:
    """cos, sin of theta_{p,i} = p / base^(2i/head_dim) for positions (T,) -> each (T, head_dim/2)."""
    i2 = torch.arange(0, head_dim, 2, dtype=torch.float32, device=positions.device)  # 2i
    inv_freq = base ** (-i2 / head_dim)  # (hd/2,)
    theta = positions.float()[:, None] * inv_freq[None, :]  # (T, hd/2)
    return theta.cos(), theta.sin()


def apply_rope(x: Tensor, cos: Tensor, sin: Tensor) -> Tensor:
    """Rotate pairs (x_{2i}, x_{2i+1}) of x (B, H, T, hd) by theta_{p,i}; cos/sin (T, hd/2)."""
    x1, x2 = x[..., 0::2], x[..., 1::2]  # (B, H, T, hd/2)
    out = torch.stack((x1 * cos - x2 * sin, x1 * sin + x2 * cos), dim=-1)  # (B, H, T, hd/2, 2)
    return out.flatten(-2).type_as(x)  # (B, H, T, hd)


class CausalSelfAttention(nn.Module):
    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.num_heads, self.head_dim = cfg.num_heads, cfg.width // cfg.num_heads
        self.qkv = nn.Linear(cfg.width, 3 * cfg.width)  # fused Q, K, V
        self.proj = nn.Linear(cfg.width, cfg.width)  # a residual projection: scaled init
        self.dropout = cfg.dropout
        self.rope = cfg.position == "rope"

    def _heads(self, x: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        B, T, d = x.shape
        q, k, v = self.qkv(x).split(d, dim=2)  # each (B, T, d)
        # (B, T, d) -> (B, T, H, hd) -> (B, H, T, hd)
        return tuple(z.view(B, T, self.num_heads, self.head_dim).transpose(1, 2) for z in (q, k, v))

    def _merge(self, y: Tensor) -> Tensor:
        B, H, T, hd = y.shape
        return self.proj(y.transpose(1, 2).reshape(B, T, H * hd))  # (B, H, T, hd) -> (B, T, d)

    def forward(self, x: Tensor, rope: tuple[Tensor, Tensor] | None = None, last: bool = False) -> Tensor:
        """x (B, T, d) -> (B, T, d), position t attends to 0..t; last: the last position only (B, 1, d)."""
        return self.prefill(x, rope, last)[0]

    def prefill(
        self,
        x: Tensor,
        rope: tuple[Tensor, Tensor] | None = None,
        last: bool = False,
        cache: tuple[Tensor, Tensor] | None = None,
        start: int = 0,
    ) -> tuple[Tensor, Tensor, Tensor]:
        """forward, also returning the keys (rotated) and values: x (B, T, d) -> y, k, v ((B, H, T, hd)).

        last: only the last query (it attends to every key, no mask): y (B, 1, d), k and v of all T.
        cache: key, value buffers (B, H, >= start + T, hd) whose positions 0..start-1 hold earlier keys and
        values: x is positions start..start+T-1 (rope must be theirs), its keys and values are written
        into the buffers there (in place) and each new position i attends to 0..start+i."""
        q, k, v = self._heads(x)  # (B, H, T, hd)
        if rope is not None:
            q, k = apply_rope(q, *rope), apply_rope(k, *rope)
        keys, values, mask, T = k, v, None, x.shape[1]
        if cache is not None:
            cache[0][:, :, start : start + T], cache[1][:, :, start : start + T] = k, v
            keys, values = cache[0][:, :, : start + T], cache[1][:, :, : start + T]  # (B, H, start+T, hd)
            if not last and T > 1:  # new i sees 0..start+i
                mask = torch.ones(T, start + T, dtype=torch.bool, device=x.device).tril(diagonal=start)
        drop = self.dropout if self.training else 0.0
        if last:
            y = F.scaled_dot_product_attention(q[:, :, -1:], keys, values, dropout_p=drop)  # (B, H, 1, hd)
        elif cache is not None:
            y = F.scaled_dot_product_attention(q, keys, values, attn_mask=mask, dropout_p=drop)
        else:
            y = F.scaled_dot_product_attention(q, k, v, dropout_p=drop, is_causal=True)  # (B, H, T, hd)
        return self._merge(y), k, v

    def branch(
        self,
        x: Tensor,
        rope: tuple[Tensor, Tensor] | None,
        shared: tuple[Tensor, Tensor] | None,
        mask: Tensor | None,
        own: tuple[Tensor, Tensor] | None,
    ) -> tuple[Tensor, Tensor, Tensor]:
        """New positions x (*G, O, n, d) of O branches per group -> (y (*G, O, n, d), k, v (*G, O, H, n, hd)).

        New query i of a branch attends to its group's shared keys and values (shared: k, v (*G, H, P, hd),
        where mask (O, n, P) allows; all if mask is None), to the branch's own earlier keys (own: k, v
        (*G, O, H, R, hd), or None) and to its new keys 0..i. Key blocks are never concatenated (only their
        scores are), and the shared block is contracted batched (einsum), not copied per branch.
        rope: cos, sin (O, n, hd/2) of every new position, or None.
        """
        *lead, n, d = x.shape
        q, k, v = self.qkv(x).split(d, dim=-1)  # each (*G, O, n, d)
        # (*G, O, n, d) -> (*G, O, n, H, hd) -> (*G, O, H, n, hd)
        q, k, v = (z.view(*lead, n, self.num_heads, self.head_dim).transpose(-2, -3) for z in (q, k, v))
        if rope is not None:
            cos, sin = (a[:, None] for a in rope)  # (O, 1, n, hd/2): the same for every head
            q, k = apply_rope(q, cos, sin), apply_rope(k, cos, sin)
        q = q * (1.0 / math.sqrt(self.head_dim))
        scores, values = [], []  # per key block: scores (*G, O, H, n, keys), weights -> (*G, O, H, n, hd)
        if shared is not None:
            past = torch.einsum("...ohnd,...hpd->...ohnp", q, shared[0])  # (*G, O, H, n, P)
            if mask is not None:
                past = past.masked_fill(~mask[:, None], float("-inf"))  # mask (O, 1, n, P)
            scores.append(past)
            values.append(lambda w: torch.einsum("...ohnp,...hpd->...ohnd", w, shared[1]))
        if own is not None:
            scores.append(_scores(q, own[0]))
            values.append(lambda w: _weighted(w, own[1]))
        new = _scores(q, k)  # (*G, O, H, n, n)
        if n > 1:
            new = new.masked_fill(~torch.ones(n, n, dtype=torch.bool, device=x.device).tril(), float("-inf"))
        scores.append(new)
        values.append(lambda w: _weighted(w, v))
        w = torch.cat(scores, dim=-1).softmax(dim=-1)
        parts = w.split([s.shape[-1] for s in scores], dim=-1)
        y = sum(value(part) for value, part in zip(values, parts, strict=True))  # (*G, O, H, n, hd)
        # (*G, O, H, n, hd) -> (*G, O, n, H * hd)
        return self.proj(y.transpose(-2, -3).reshape(*lead, n, d)), k, v

    def step(
        self,
        x: Tensor,
        cache_k: Tensor,
        cache_v: Tensor,
        slot: int,
        filled: int,
        rope: tuple[Tensor, Tensor] | None = None,
    ) -> Tensor:
        """New position x (B, 1, d): write its key/value into `slot`, attend over `filled` cached slots."""
        q, k, v = self._heads(x)  # (B, H, 1, hd)
        if rope is not None:
            q, k = apply_rope(q, *rope), apply_rope(k, *rope)
        cache_k[:, :, slot] = k[:, :, 0]
        cache_v[:, :, slot] = v[:, :, 0]
        # every cached key is in the past, so no mask; softmax does not depend on the slot order
        y = F.scaled_dot_product_attention(q, cache_k[:, :, :filled], cache_v[:, :, :filled])  # (B, H, 1, hd)
        return self._merge(y)


def _scores(q: Tensor, k: Tensor) -> Tensor:
    """q (..., n, hd), k (..., R, hd) -> q k^T (..., n, R); one query: a product and a sum, not matmuls."""
    return (q * k).sum(-1)[..., None, :] if q.shape[-2] == 1 else q @ k.mT


def _weighted(w: Tensor, v: Tensor) -> Tensor:
    """w (..., n, R), v (..., R, hd) -> w v (..., n, hd)."""
    return (w.mT * v).sum(-2, keepdim=True) if w.shape[-2] == 1 else w @ v
