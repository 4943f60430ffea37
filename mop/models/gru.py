"""GRU baseline with the transformer's read-in / read-out and the same forward / loss / streaming API.

    h_t = GRU(W_in z_t, h_{t-1}),  yhat_{t+1} = W_out LN(h_t)   (num_layers stacked GRU layers of width d)

No context limit: forward takes any T, and streaming carries the hidden state (B, L, d) step by step, which
equals the full forward exactly. Registered as arch "gru"; read-out and loss from mop.models.heads.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from mop.config import ModelConfig
from mop.errors import MopError
from mop.models.features import gap_positions
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


class GRUCache:
    """Hidden state h (L, B, d) and the number of inputs consumed."""

    def __init__(self, h: Tensor) -> None:
        self.h = h
        self.t = 0


@register_model("gru", skip_presets=("small", "smoke"))
class GRUModel(LearnedModel):
    context_limited = False  # forward takes any T
    supports_stream = True  # the hidden state, step by step: equal to forward
    supports_branch = False
    branchable_state = True  # GRUCache.h is the whole state (mop.models.rollout.recurrent_forecast)
    has_direct_heads = True
    supports_features = False  # no input features (refused below)
    reads_features = False

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__(cfg)
        check_dims(cfg)
        if cfg.input_scale != "none" or cfg.rls_order > 0 or cfg.arx_order > 0 or cfg.record_norm != "none":
            raise MopError(
                "model.input_scale, record_norm and rls_order are options of arch 'gpt', not of the GRU"
            )
        self.read_in = nn.Linear(cfg.input_dim, cfg.width)
        self.gru = nn.GRU(
            cfg.width,
            cfg.width,
            num_layers=cfg.num_layers,
            batch_first=True,
            dropout=cfg.dropout if cfg.num_layers > 1 else 0.0,
        )
        self.ln_f = nn.LayerNorm(cfg.width)
        self.read_out = nn.Linear(cfg.width, horizon_dim(cfg))  # one-step read-out, then any k-step heads
        self.future_head = future_head(cfg)  # k-step heads on a system with inputs (mop.models.horizons)

    def _outputs(
        self, inputs: Tensor, h0: Tensor | None = None, future: Tensor | None = None
    ) -> tuple[Tensor, Tensor | None, Tensor | None, Tensor]:
        """inputs (B, T, d_in) -> mean (B, T, m), var|None, k-step heads (B, T, K-1, m)|None and the final
        hidden state (L, B, d); future: the heads' future inputs (mop.models.horizons.add_future_inputs)."""
        out, h = self.gru(self.read_in(inputs), h0)  # (B, T, d), (L, B, d)
        hidden = self.ln_f(out)
        mu, var, later = split_horizons(self.read_out(hidden), self.cfg)
        later = add_future_inputs(self.future_head, later, hidden, inputs, self.cfg, future)
        return mu, var, later, h

    def _run(self, inputs: Tensor, h0: Tensor | None = None) -> tuple[Tensor, Tensor | None, Tensor]:
        """inputs (B, T, d_in) -> mean (B, T, m), var (B, T, m)|None, final hidden (L, B, d)."""
        mu, var, _, h = self._outputs(inputs, h0)
        return mu, var, h

    def forecast_heads(self, inputs: Tensor, last: bool = False, future: Tensor | None = None) -> Tensor:
        """inputs (B, T, d_in) -> (B, T, K, m): [:, t, k-1] is head k's mean of y_{t+k} from z_0..z_t and
        u_{t+1}..u_{t+k-1}; future (B, T, K-1, k): those inputs (default: the inputs' own, shifted);
        last: the last position's only (B, 1, K, m)."""
        mu, _, later, _ = self._outputs(inputs, future=future)
        heads = stack_heads(mu, later)
        return heads[:, -1:] if last else heads

    def forward(self, inputs: Tensor) -> Tensor:
        """inputs (B, T, d_in) -> mean predictions (B, T, m); position t predicts y_{t+1}."""
        return self._run(inputs)[0]

    def predict_distribution(self, inputs: Tensor) -> tuple[Tensor, Tensor]:
        require_gaussian(self.cfg)
        mu, var, _ = self._run(inputs)
        return mu, var

    def loss(self, inputs: Tensor, targets: Tensor) -> Tensor:
        mu, var, later, _ = self._outputs(inputs)
        cfg, gaps = self.cfg, gap_positions(inputs, self.cfg)
        return horizon_loss(mu, var, later, targets, cfg.observation_mask, cfg.horizon_loss, gaps)

    def init_cache(self, batch_size: int) -> GRUCache:
        p = self.read_in.weight
        h = torch.zeros(self.cfg.num_layers, batch_size, self.cfg.width, device=p.device, dtype=p.dtype)
        return GRUCache(h)  # h (L, B, d)

    def step_distribution(self, z: Tensor, cache: GRUCache) -> tuple[Tensor, Tensor | None]:
        """z_t (B, d_in) -> (mean, var|None) of y_{t+1}, each (B, m); updates the cache."""
        mu, var, cache.h = self._run(z[:, None, :], cache.h)  # (B, 1, m)
        cache.t += 1
        return mu[:, 0], None if var is None else var[:, 0]

    def step(self, z: Tensor, cache: GRUCache) -> Tensor:
        return self.step_distribution(z, cache)[0]
