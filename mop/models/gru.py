"""GRU baseline with the transformer's read-in / read-out and the same forward / loss / streaming API.

    h_t = GRU(W_in z_t, h_{t-1}),  yhat_{t+1} = W_out LN(h_t)   (num_layers stacked GRU layers of width d)

No context limit: forward takes any T, and streaming carries the hidden state (L, B, d) step by step, which
equals the full forward exactly. Registered as arch "gru"; the read-out, loss and streaming are
mop.models.recurrent's.
"""

from __future__ import annotations

from torch import Tensor, nn

from mop.config import ModelConfig
from mop.models.recurrent import RecurrentModel, zeros_like_params
from mop.models.registry import register_model


@register_model("gru", skip_presets=("small", "smoke"))
class GRUModel(RecurrentModel):
    label = "the GRU"

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__(cfg)
        self.gru = nn.GRU(
            cfg.width,
            cfg.width,
            num_layers=cfg.num_layers,
            batch_first=True,
            dropout=cfg.dropout if cfg.num_layers > 1 else 0.0,
        )
        self._build_read_out(cfg)

    def _body(self, x: Tensor, h0: Tensor | None) -> tuple[Tensor, Tensor]:
        return self.gru(x, h0)  # (B, T, d), (L, B, d)

    def _zero_state(self, batch_size: int) -> Tensor:
        return zeros_like_params(self, self.cfg.num_layers, batch_size, self.cfg.width)
