"""The GPT-2 body of the paper's model: a plain causal sequence model on real-valued vectors (nanoGPT-style).

    x (B, T, D) -> read-in (D -> d) [+ learned positions] -> L blocks -> LayerNorm -> hidden h (B, T, d)
    h -> read-out (d -> horizon_dim): one-step mean (B, T, m), var|None, the k-step heads' linear part

Position t reads x_0..x_t only, and its read-out is the prediction of y_{t+1} in the body's own units: the
model wraps the body in its feature front end (mop.models.frontend), which makes x from the raw inputs and
maps the read-out back (mop.models.transformer). Blocks are pre-LayerNorm (causal self-attention,
mop.models.attention, then a GELU MLP 4x); GPT-2's init (N(0, 0.02), residual projections scaled by
1 / sqrt(2 L)). Three ways through the same weights:
- hidden / heads: a whole window at once (at most cfg.context positions);
- prefill / branch: a window's keys and values, then many continuations of it (mop.models.rollout);
- init_kv / step_hidden: one position at a time on a circular KV cache of `context` slots (streaming),
  equal to hidden on the prefix inside the context; beyond it see mop.models.transformer.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from mop.config import ModelConfig
from mop.errors import MopError
from mop.models.attention import CausalSelfAttention, rope_angles
from mop.models.horizons import horizon_dim, split_horizons


class MLP(nn.Module):
    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.fc = nn.Linear(cfg.width, 4 * cfg.width)
        self.proj = nn.Linear(4 * cfg.width, cfg.width)  # a residual projection: scaled init
        self.drop = nn.Dropout(cfg.dropout)

    def forward(self, x: Tensor) -> Tensor:
        return self.drop(self.proj(F.gelu(self.fc(x))))  # (B, T, d)


class Block(nn.Module):
    """Pre-LayerNorm residual block: x + attn(ln(x)), then x + mlp(ln(x))."""

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.ln_1, self.attn = nn.LayerNorm(cfg.width), CausalSelfAttention(cfg)
        self.ln_2, self.mlp = nn.LayerNorm(cfg.width), MLP(cfg)

    def forward(self, x: Tensor, rope: tuple[Tensor, Tensor] | None = None, last: bool = False) -> Tensor:
        """x (B, T, d) -> (B, T, d); last: the last position only (B, 1, d)."""
        return self.prefill(x, rope, last)[0]

    def prefill(
        self,
        x: Tensor,
        rope: tuple[Tensor, Tensor] | None,
        last: bool = False,
        cache: tuple[Tensor, Tensor] | None = None,
        start: int = 0,
    ) -> tuple[Tensor, Tensor, Tensor]:
        """forward, also returning this layer's keys and values (B, H, T, hd); see CausalSelfAttention."""
        a, k, v = self.attn.prefill(self.ln_1(x), rope, last, cache, start)
        x = (x[:, -1:] if last else x) + a
        return x + self.mlp(self.ln_2(x)), k, v

    def branch(
        self,
        x: Tensor,
        rope: tuple[Tensor, Tensor] | None,
        shared: tuple[Tensor, Tensor] | None,
        mask: Tensor | None,
        own: tuple[Tensor, Tensor] | None,
    ) -> tuple[Tensor, Tensor, Tensor]:
        """CausalSelfAttention.branch inside the residual block: x (*G, O, n, d) -> (x, k, v)."""
        a, k, v = self.attn.branch(self.ln_1(x), rope, shared, mask, own)
        x = x + a
        return x + self.mlp(self.ln_2(x)), k, v

    def step(
        self,
        x: Tensor,
        cache_k: Tensor,
        cache_v: Tensor,
        slot: int,
        filled: int,
        rope: tuple[Tensor, Tensor] | None = None,
    ) -> Tensor:
        x = x + self.attn.step(self.ln_1(x), cache_k, cache_v, slot, filled, rope)
        return x + self.mlp(self.ln_2(x))


class KVCache:
    """Per-layer circular key/value buffers (L, B, H, context, hd) and the number of inputs seen so far."""

    def __init__(self, cfg: ModelConfig, batch_size: int, device: torch.device, dtype: torch.dtype) -> None:
        shape = (cfg.num_layers, batch_size, cfg.num_heads, cfg.context, cfg.width // cfg.num_heads)
        self.k = torch.zeros(shape, device=device, dtype=dtype)
        self.v = torch.zeros(shape, device=device, dtype=dtype)
        self.context = cfg.context
        self.t = 0  # inputs consumed


class GPTBody(nn.Module):
    """The body (module docstring): inputs (B, T, input_dim) -> hidden (B, T, d) -> read-out heads.

    Its parameters (read_in, wpe, blocks, ln_f, read_out) are named as the shipped models' state_dicts name
    them. It initialises nn.Module itself and keeps cfg as self.cfg, so a LearnedModel may derive from it
    (mop.models.transformer.Transformer) and keep those names at the top level."""

    def __init__(self, cfg: ModelConfig, input_dim: int) -> None:
        nn.Module.__init__(self)
        self.cfg = cfg
        self.read_in = nn.Linear(input_dim, cfg.width)
        self.wpe = nn.Embedding(cfg.context, cfg.width) if cfg.position == "learned" else None
        self.drop = nn.Dropout(cfg.dropout)
        self.blocks = nn.ModuleList(Block(cfg) for _ in range(cfg.num_layers))
        self.ln_f = nn.LayerNorm(cfg.width)
        self.read_out = nn.Linear(cfg.width, horizon_dim(cfg))  # one-step read-out, then any k-step heads
        residual = {id(p) for b in self.blocks for p in (b.attn.proj, b.mlp.proj)}  # scaled init
        self.apply(lambda module: self._init_weights(module, id(module) in residual))

    def _init_weights(self, module: nn.Module, residual: bool) -> None:
        """GPT-2 init: N(0, 0.02), residual projections N(0, 0.02 / sqrt(2 L)), zero biases."""
        if isinstance(module, nn.Linear):
            std = 0.02 / math.sqrt(2 * self.cfg.num_layers) if residual else 0.02
            nn.init.normal_(module.weight, mean=0.0, std=std)
            nn.init.zeros_(module.bias)
        elif isinstance(module, nn.Embedding):
            nn.init.normal_(module.weight, mean=0.0, std=0.02)

    def _rope(self, positions: Tensor) -> tuple[Tensor, Tensor] | None:
        if self.wpe is not None:
            return None
        return rope_angles(positions, self.cfg.width // self.cfg.num_heads)

    def hidden(self, inputs: Tensor, last: bool = False) -> Tensor:
        """Body inputs (B, T, input_dim) -> final hidden (B, T, d); h_t reads inputs 0..t.

        last: the last position's only (B, 1, d); the last block then skips the others' attention output
        and MLP, which nothing reads (a sliding window keeps only its last output)."""
        B, T, _ = inputs.shape
        if T > self.cfg.context:
            raise MopError(
                f"sequence of length {T} exceeds model.context={self.cfg.context}; "
                "use LearnedPredictor(mode='window' or 'stream') for longer trajectories"
            )
        positions = torch.arange(T, device=inputs.device)
        h = self._embed(inputs, positions)  # (B, T, d)
        rope = self._rope(positions)
        for i, block in enumerate(self.blocks):
            h = block(h, rope, last and i == len(self.blocks) - 1)
        return self.ln_f(h)  # (B, T, d), or (B, 1, d)

    def _embed(self, inputs: Tensor, positions: Tensor) -> Tensor:
        """Read-in plus learned position embeddings: inputs (..., T, D), positions (T,) or (O, n)."""
        h = self.read_in(inputs)  # (..., T, d)
        if self.wpe is not None:
            h = h + self.wpe(positions)  # (T, d) broadcast over the leading dims
        return self.drop(h)

    def heads(self, h: Tensor) -> tuple[Tensor, Tensor | None, Tensor | None]:
        """Final hidden (B, T, d) -> the read-out at position t in the body's units: one-step mean of
        y_{t+1} (B, T, m), its var (B, T, m)|None, and the k-step heads' linear part (B, T, K-1, m)|None
        (mop.models.horizons.split_horizons)."""
        return split_horizons(self.read_out(h), self.cfg)

    # ---- branching (k-step forecasts from many origins at once: mop.models.rollout) ----
    def prefill(
        self,
        inputs: Tensor,
        last: bool = False,
        cache: list[tuple[Tensor, Tensor]] | None = None,
        start: int = 0,
    ) -> tuple[Tensor, list[tuple[Tensor, Tensor]]]:
        """inputs (B, T, D) -> (one-step mean (B, T, m), every layer's keys, values (B, H, T, hd)).

        last: the mean at the last position only (B, 1, m); the keys and values are still every position's.
        cache: per layer key, value buffers (B, H, C, hd) holding a window's positions 0..start-1 (from an
        earlier prefill): the inputs continue that window at positions start..start+T-1 (start + T <= C),
        their keys and values are written into the buffers there (in place, so positions < start stay
        valid for a later call with a smaller start), and the result equals a prefill of the whole window
        at those positions."""
        positions = torch.arange(start, start + inputs.shape[-2], device=inputs.device)
        h, rope = self._embed(inputs, positions), self._rope(positions)
        kv = []
        for i, block in enumerate(self.blocks):
            layer_cache = None if cache is None else cache[i]
            h, k, v = block.prefill(h, rope, last and i == len(self.blocks) - 1, layer_cache, start)
            kv.append((k, v))
        return self.heads(self.ln_f(h))[0], kv

    def branch(
        self,
        inputs: Tensor,
        positions: Tensor,
        shared: list[tuple[Tensor, Tensor]] | None,
        mask: Tensor | None = None,
        own: list[tuple[Tensor, Tensor]] | None = None,
    ) -> tuple[Tensor, list[tuple[Tensor, Tensor]]]:
        """Continue O branches per group by n new inputs each (CausalSelfAttention.branch, per layer).

        inputs (*G, O, n, D) at window positions (O, n) (each < context); shared: per layer the group's
        keys, values (*G, H, P, hd) (from prefill) that `mask` (O, n, P) allows; own: per layer each branch's
        earlier keys, values (*G, O, H, R, hd). Returns the one-step mean (*G, O, n, m) and per layer the new
        keys, values (*G, O, H, n, hd).
        """
        h = self._embed(inputs, positions)  # (*G, O, n, d)
        rope = None
        if self.wpe is None:
            cos, sin = rope_angles(positions.flatten(), self.cfg.width // self.cfg.num_heads)  # (O n, hd/2)
            rope = cos.view(*positions.shape, -1), sin.view(*positions.shape, -1)  # (O, n, hd/2)
        new = []
        for layer, block in enumerate(self.blocks):
            layer_shared = None if shared is None else shared[layer]
            h, k, v = block.branch(h, rope, layer_shared, mask, None if own is None else own[layer])
            new.append((k, v))
        return self.heads(self.ln_f(h))[0], new

    # ---- streaming ----
    def init_kv(self, batch_size: int) -> KVCache:
        """An empty KV cache for batch_size streams, on the body's device and dtype."""
        p = self.read_in.weight
        return KVCache(self.cfg, batch_size, p.device, p.dtype)

    def step_hidden(self, x: Tensor, cache: KVCache) -> Tensor:
        """One body input x_t (B, 1, D) -> final hidden h_t (B, 1, d); writes its keys and values into
        `cache` (slot t mod context) and advances cache.t. Position t + 1 beyond the context takes the
        last learned position embedding (position="learned")."""
        t, C = cache.t, self.cfg.context
        slot, filled = t % C, min(t + 1, C)
        h = self.read_in(x)  # (B, 1, d)
        position = torch.tensor([t], device=x.device)
        if self.wpe is not None:
            h = h + self.wpe(position.clamp_max(C - 1))  # (1, d)
        rope = self._rope(position)
        for layer, block in enumerate(self.blocks):
            h = block.step(h, cache.k[layer], cache.v[layer], slot, filled, rope)
        cache.t = t + 1
        return self.ln_f(h)  # (B, 1, d)
