"""The paper's model: a GPT-2-style causal transformer on real-valued inputs (nanoGPT-style, top to bottom).

    config -> (attention: mop.models.attention) -> MLP -> block -> KV cache -> model

Inputs are z_t = [y_t, u_t] (B, T, d_in). A linear read-in maps them to width d, GPT-2 adds learned
absolute position embeddings, L pre-LayerNorm blocks (causal self-attention + GELU MLP 4x) follow, a final
LayerNorm and a linear read-out give the prediction. Output position t predicts y_{t+1} from z_0..z_t:

    mean readout:      yhat_{t+1} = W_out h_t                          loss = MSE
    gaussian readout:  [mu, s] = W_out h_t, var = softplus(s) + 1e-6
                       loss = mean_{t,i} 0.5 [log(2 pi var) + (y - mu)^2 / var]     (mop.models.heads)

`predict_distribution` raises MopError for the mean readout (it has no variance). Registered as arch "gpt".
Options model.input_scale = "running" and model.rls_order = p add causal input features (a running output
scale, the RLS-AR(p) one-step prediction) and map the read-out back (mop.models.features); off by default.

Streaming (`init_cache` / `step`): one new input per call, keys and values of past inputs kept in a
circular cache of `context` slots per layer, so every step costs O(context) however long the stream runs.
- Inside the context (t < context) `step` equals `forward` on the prefix (to float rounding).
- Beyond it the oldest slot is overwritten (a rolling window of the last `context` keys/values). The cached
  keys were computed when older inputs were still visible in the layers below, so this approximates the
  paper's sliding window and is not equal to it.
  * position="rope": positions enter only as relative distances (all <= context-1, the range seen in
    training); the recommended setting for long streams.
  * position="learned": the new input gets the last learned embedding, index min(t, context-1); the cached
    keys keep the positions they were written with.
  Use LearnedPredictor(mode="sliding") for the paper's exact sliding window (mop.models.predict).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from mop.config import ModelConfig
from mop.errors import MopError
from mop.models.attention import CausalSelfAttention, rope_angles
from mop.models.features import (
    FeatureState,
    augment,
    check_features,
    extra_input_dim,
    gap_positions,
    reads_features,
    restore,
)
from mop.models.heads import check_dims, require_gaussian
from mop.models.horizons import (
    add_future_inputs,
    future_head,
    horizon_dim,
    horizon_loss,
    split_horizons,
    stack_heads,
)
from mop.models.interface import LearnedModel
from mop.models.registry import register_model


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
        self.features = FeatureState(cfg, batch_size, device, dtype)  # running scale / RLS fit


@register_model("gpt", predictor="mop")
class Transformer(LearnedModel):
    """GPT-2 body with a linear read-in (d_in -> d) and read-out (d -> m, or 2m for the Gaussian readout)."""

    context_limited = True  # at most cfg.context inputs per forward (LearnedPredictor windows longer ones)
    supports_stream = True  # the rolling KV cache: equal to forward inside the context
    supports_branch = True  # prefill / branch (mop.models.rollout), unless it reads features
    branchable_state = False
    has_direct_heads = True
    supports_features = True  # model.input_scale / rls_order / arx_order (mop.models.features)

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__(cfg)
        check_dims(cfg)
        check_features(cfg)
        self.read_in = nn.Linear(cfg.input_dim + extra_input_dim(cfg), cfg.width)
        self.wpe = nn.Embedding(cfg.context, cfg.width) if cfg.position == "learned" else None
        self.drop = nn.Dropout(cfg.dropout)
        self.blocks = nn.ModuleList(Block(cfg) for _ in range(cfg.num_layers))
        self.ln_f = nn.LayerNorm(cfg.width)
        self.read_out = nn.Linear(cfg.width, horizon_dim(cfg))  # one-step read-out, then any k-step heads
        residual = {id(p) for b in self.blocks for p in (b.attn.proj, b.mlp.proj)}  # scaled init
        self.apply(lambda module: self._init_weights(module, id(module) in residual))
        self.future_head = future_head(cfg)  # k-step heads on a system with inputs (mop.models.horizons)
        if cfg.rls_order > 0:  # the read-out predicts the residual on RLS: start as the RLS predictor
            nn.init.zeros_(self.read_out.weight)

    @property
    def reads_features(self) -> bool:
        """The running scale, record normalisation or RLS / ARX feature is on (mop.models.features)."""
        return reads_features(self.cfg)

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
        """Network inputs (B, T, d_in + extra; mop.models.features.augment) -> final hidden (B, T, d).

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
        """Read-in plus learned position embeddings: inputs (..., T, d_in), positions (T,) or (O, n)."""
        h = self.read_in(inputs)  # (..., T, d)
        if self.wpe is not None:
            h = h + self.wpe(positions)  # (T, d) broadcast over the leading dims
        return self.drop(h)

    def _read_out(self, h: Tensor) -> tuple[Tensor, Tensor | None]:
        """Final hidden states (B, T, d) -> one-step mean (B, T, m), var (B, T, m) or None."""
        return split_horizons(self.read_out(h), self.cfg)[:2]

    def _outputs(
        self, inputs: Tensor, last: bool = False, future: Tensor | None = None
    ) -> tuple[Tensor, Tensor | None, Tensor | None]:
        """inputs (B, T, d_in) -> one-step mean (B, T, m), var (B, T, m)|None and the k-step heads' means
        (B, T, K-1, m)|None, in the inputs' units (T = 1: last). future: the k-step heads' future inputs
        (mop.models.horizons.add_future_inputs). The features' scale and base restore every head (a k-step
        head predicts its residual on the one-step RLS prediction)."""
        z, scale, base = augment(inputs, self.cfg)  # (B, T, d_in + extra), (B, T, 1)|None, (B, T, m)|None
        if last:
            scale, base = (None if a is None else a[:, -1:] for a in (scale, base))
        h = self.hidden(z, last)
        mu, var, later = split_horizons(self.read_out(h), self.cfg)
        later = add_future_inputs(self.future_head, later, h, inputs, self.cfg, future, last)
        if later is not None:
            later = restore(later, None, *(None if a is None else a[:, :, None] for a in (scale, base)))[0]
        return (*restore(mu, var, scale, base), later)

    def _distribution(self, inputs: Tensor, last: bool = False) -> tuple[Tensor, Tensor | None]:
        """inputs (B, T, d_in) -> mean (B, T, m), var (B, T, m)|None in the inputs' units (T = 1: last)."""
        return self._outputs(inputs, last)[:2]

    def forecast_heads(self, inputs: Tensor, last: bool = False, future: Tensor | None = None) -> Tensor:
        """inputs (B, T, d_in) -> (B, T, K, m): [:, t, k-1] is head k's mean of y_{t+k} from z_0..z_t and
        u_{t+1}..u_{t+k-1} (k = 1 is forward's prediction); last: the last position's only (B, 1, K, m).
        future (B, T or 1, K-1, k): those future inputs (default: the inputs' own, shifted)."""
        mu, _, later = self._outputs(inputs, last, future)
        return stack_heads(mu, later)

    def forward(self, inputs: Tensor, last: bool = False) -> Tensor:
        """inputs (B, T, d_in) -> mean predictions (B, T, m); position t predicts y_{t+1}.
        last: the last position's only (B, 1, m)."""
        return self._distribution(inputs, last)[0]

    def predict_distribution(self, inputs: Tensor, last: bool = False) -> tuple[Tensor, Tensor]:
        """Gaussian readout: (mean, var) each (B, T, m), (B, 1, m) if last. MopError for readout 'mean'."""
        require_gaussian(self.cfg)
        return self._distribution(inputs, last)

    def loss(self, inputs: Tensor, targets: Tensor) -> Tensor:
        """MSE (readout 'mean') or mean Gaussian NLL (readout 'gaussian'); targets (B, T, m). With k-step
        heads the mean over k of each head's loss (mop.models.heads.horizon_loss)."""
        cfg = self.cfg
        gaps = gap_positions(inputs, cfg)
        return horizon_loss(*self._outputs(inputs), targets, cfg.observation_mask, cfg.horizon_loss, gaps)

    # ---- branching (k-step forecasts from many origins at once: mop.models.rollout) ----
    def prefill(
        self,
        inputs: Tensor,
        last: bool = False,
        cache: list[tuple[Tensor, Tensor]] | None = None,
        start: int = 0,
    ) -> tuple[Tensor, list[tuple[Tensor, Tensor]]]:
        """inputs (B, T, d_in) -> (mean (B, T, m) as forward, every layer's keys, values (B, H, T, hd)).

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
        return self._read_out(self.ln_f(h))[0], kv

    def branch(
        self,
        inputs: Tensor,
        positions: Tensor,
        shared: list[tuple[Tensor, Tensor]] | None,
        mask: Tensor | None = None,
        own: list[tuple[Tensor, Tensor]] | None = None,
    ) -> tuple[Tensor, list[tuple[Tensor, Tensor]]]:
        """Continue O branches per group by n new inputs each (CausalSelfAttention.branch, per layer).

        inputs (*G, O, n, d_in) at window positions (O, n) (each < context); shared: per layer the group's
        keys, values (*G, H, P, hd) (from prefill) that `mask` (O, n, P) allows; own: per layer each branch's
        earlier keys, values (*G, O, H, R, hd). Returns the mean (*G, O, n, m) and per layer the new keys,
        values (*G, O, H, n, hd).
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
        return self._read_out(self.ln_f(h))[0], new

    # ---- streaming ----
    def init_cache(self, batch_size: int) -> KVCache:
        p = self.read_in.weight
        return KVCache(self.cfg, batch_size, p.device, p.dtype)

    def step_distribution(self, z: Tensor, cache: KVCache) -> tuple[Tensor, Tensor | None]:
        """One input z_t (B, d_in) -> (mean, var|None) of y_{t+1}, each (B, m); updates `cache` in place."""
        t, C = cache.t, self.cfg.context
        slot, filled = t % C, min(t + 1, C)
        z_net, scale, base = cache.features.step(z)  # (B, 1, d_in + extra), (B, 1, 1)|None, (B, 1, m)|None
        h = self.read_in(z_net)  # (B, 1, d)
        position = torch.tensor([t], device=z.device)
        if self.wpe is not None:
            h = h + self.wpe(position.clamp_max(C - 1))  # (1, d)
        rope = self._rope(position)
        for layer, block in enumerate(self.blocks):
            h = block.step(h, cache.k[layer], cache.v[layer], slot, filled, rope)
        cache.t = t + 1
        mu, var = restore(*self._read_out(self.ln_f(h)), scale, base)  # (B, 1, m)
        return mu[:, 0], None if var is None else var[:, 0]

    def step(self, z: Tensor, cache: KVCache) -> Tensor:
        """One input z_t (B, d_in) -> mean prediction of y_{t+1} (B, m)."""
        return self.step_distribution(z, cache)[0]
