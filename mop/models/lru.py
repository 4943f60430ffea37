"""A deep linear recurrent unit (LRU) body with the GRU's read-in / read-out: the recurrent state-space body
of the field's best long free runs (deep LRU: Forgione, Mejari, Piga, CDC 2024), in the registry beside the
transformer so both train with the same losses (the simulation loss of model.observation_mask +
train.simulate_after included) and are measured side by side.

    x^0_t = W_in z_t
    x^l_t = x^{l-1}_t + GLU(W_l GELU(LRU_l(LN_l(x^{l-1}))_t))     l = 1..L (model.num_layers)
    yhat_{t+1} = W_out LN(x^L_t)

Each LRU_l (mop.simulators.lru.LRU, width d = model.width, d complex modes) is linear and stable by
construction; forward runs it over the window by a parallel scan (log2 T steps), which equals its
step-by-step loop (tests/test_lru_model.py). The state is the L layers' complex modes (L, B, d); streaming
carries it one input at a time and equals forward. Registered as arch "deep-lru" (not "lru": that is
`mop benchmark --predictors lru`, the encoder-started simulator of mop.simulators), trained only when asked
(every preset leaves it out of the experiments: `--with deep-lru`, or `model.arch=deep-lru`).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from mop.config import ModelConfig
from mop.models.horizons import split_horizons
from mop.models.recurrent import RecurrentModel
from mop.models.registry import register_model
from mop.simulators.lru import LRU

NAME = "deep-lru"  # the registry's name (not "lru": `mop benchmark --predictors lru` is mop.simulators' LRU)


@register_model(NAME, skip_presets=("paper", "small", "smoke"))
class LRUModel(RecurrentModel):
    label = "the LRU"

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__(cfg)
        d, L = cfg.width, cfg.num_layers
        self.norms = nn.ModuleList(nn.LayerNorm(d) for _ in range(L))
        self.lrus = nn.ModuleList(LRU(d, d) for _ in range(L))
        self.glus = nn.ModuleList(nn.Linear(d, 2 * d) for _ in range(L))
        self.dropout = nn.Dropout(cfg.dropout)
        self._build_read_out(cfg)

    def _body(self, x: Tensor, h0: Tensor | None, loop: bool = False) -> tuple[Tensor, Tensor]:
        """x (B, T, d) -> (x^L (B, T, d), the modes after x_{T-1} (L, B, d) complex); loop: each LRU step
        by step (the reference its parallel scan is tested against)."""
        states = []
        for i, (norm, lru, glu) in enumerate(zip(self.norms, self.lrus, self.glus, strict=True)):
            y, h = (lru.loop if loop else lru)(norm(x), None if h0 is None else h0[i])
            x = x + self.dropout(nn.functional.glu(glu(nn.functional.gelu(y)), dim=-1))
            states.append(h)
        return x, torch.stack(states)

    def _zero_state(self, batch_size: int) -> Tensor:
        p = self.read_in.weight
        zeros = p.new_zeros(self.cfg.num_layers, batch_size, self.cfg.width)
        return torch.complex(zeros, zeros)

    def loop_forward(self, inputs: Tensor) -> Tensor:
        """forward with each LRU run step by step (its reference): (B, T, d_in) -> (B, T, m)."""
        out, _ = self._body(self.read_in(inputs), None, loop=True)
        return split_horizons(self.read_out(self.ln_f(out)), self.cfg)[0]
