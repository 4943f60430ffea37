"""What the recurrent architectures (mop.models.gru, mop.models.lru) share: the read-in, the read-out and the
k-step heads around a body that carries a state, and the forward / loss / streaming API on top of it.

    x_t = W_in z_t,  (o_t, h_t) = body(x_t, h_{t-1}),  yhat_{t+1} = W_out LN(o_t)

No context limit: forward takes any T, and streaming carries the body's state h (L, B, ...) step by step,
which equals the full forward exactly. A subclass builds its body between read_in and the read-out
(`_build_read_out` after it: a seed draws the weights in that order) and defines `_body` and `_zero_state`.
"""

from __future__ import annotations

from abc import abstractmethod

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


class RecurrentCache:
    """The body's state h (L, B, ...) and the number of inputs consumed."""

    def __init__(self, h: Tensor) -> None:
        self.h = h
        self.t = 0


class RecurrentModel(LearnedModel):
    """A read-in, a recurrent body and the read-out (see the module docstring)."""

    context_limited = False  # forward takes any T
    supports_stream = True  # the state, step by step: equal to forward
    supports_branch = False
    branchable_state = True  # RecurrentCache.h is the whole state (mop.models.rollout.recurrent_forecast)
    has_direct_heads = True
    supports_features = False  # no input features (refused below)
    reads_features = False
    label = "a recurrent model"  # in the refusal of the features

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__(cfg)
        check_dims(cfg)
        if cfg.input_scale != "none" or cfg.rls_order > 0 or cfg.arx_order > 0 or cfg.record_norm != "none":
            raise MopError(
                f"model.input_scale, record_norm and rls_order are options of arch 'gpt', not of {self.label}"
            )
        self.read_in = nn.Linear(cfg.input_dim, cfg.width)

    def _build_read_out(self, cfg: ModelConfig) -> None:
        self.ln_f = nn.LayerNorm(cfg.width)
        self.read_out = nn.Linear(cfg.width, horizon_dim(cfg))  # one-step read-out, then any k-step heads
        self.future_head = future_head(cfg)  # k-step heads on a system with inputs (mop.models.horizons)

    @abstractmethod
    def _body(self, x: Tensor, h0: Tensor | None) -> tuple[Tensor, Tensor]:
        """x (B, T, d) read in, h0 the state before x_0 (None: zero) -> (outputs (B, T, d), final state)."""

    @abstractmethod
    def _zero_state(self, batch_size: int) -> Tensor:
        """The state before any input, for batch_size systems: (L, B, ...)."""

    def _outputs(
        self, inputs: Tensor, h0: Tensor | None = None, future: Tensor | None = None
    ) -> tuple[Tensor, Tensor | None, Tensor | None, Tensor]:
        """inputs (B, T, d_in) -> mean (B, T, m), var|None, k-step heads (B, T, K-1, m)|None and the final
        state; future: the heads' future inputs (mop.models.horizons.add_future_inputs)."""
        out, h = self._body(self.read_in(inputs), h0)
        hidden = self.ln_f(out)
        mu, var, later = split_horizons(self.read_out(hidden), self.cfg)
        later = add_future_inputs(self.future_head, later, hidden, inputs, self.cfg, future)
        return mu, var, later, h

    def _run(self, inputs: Tensor, h0: Tensor | None = None) -> tuple[Tensor, Tensor | None, Tensor]:
        """inputs (B, T, d_in) -> mean (B, T, m), var (B, T, m)|None, final state."""
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

    def init_cache(self, batch_size: int) -> RecurrentCache:
        return RecurrentCache(self._zero_state(batch_size))

    def step_distribution(self, z: Tensor, cache: RecurrentCache) -> tuple[Tensor, Tensor | None]:
        """z_t (B, d_in) -> (mean, var|None) of y_{t+1}, each (B, m); updates the cache."""
        mu, var, cache.h = self._run(z[:, None, :], cache.h)  # (B, 1, m)
        cache.t += 1
        return mu[:, 0], None if var is None else var[:, 0]

    def step(self, z: Tensor, cache: RecurrentCache) -> Tensor:
        return self.step_distribution(z, cache)[0]


def zeros_like_params(module: nn.Module, *shape: int, dtype: torch.dtype | None = None) -> Tensor:
    """Zeros of `shape` on the module's device, in its parameters' dtype (or `dtype`)."""
    p = next(module.parameters())
    return torch.zeros(*shape, device=p.device, dtype=dtype or p.dtype)
