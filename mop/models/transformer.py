"""The paper's model: the GPT-2 body (mop.models.gpt_body) inside the feature front end (mop.models.frontend).

    inputs z (B, T, d_in) --front end: encode--> x (B, T, d_in + extra) --body--> h (B, T, d)
    h --read-out--> one-step mean, var (+ k-step heads) --front end: decode--> predictions (B, T, m)

Inputs are z_t = [y_t, u_t] (B, T, d_in) (with model.observation_mask: [y_t zero-filled, u_t, observed_t]).
Output position t predicts y_{t+1} from z_0..z_t:

    mean readout:      yhat_{t+1} = decode(W_out h_t)                          loss = MSE
    gaussian readout:  [mu, s] = W_out h_t, var = softplus(s) + 1e-6, both decoded
                       loss = mean_{t,i} 0.5 [log(2 pi var) + (y - mu)^2 / var]     (mop.models.heads)

With every feature option off (the paper's model) encode and decode are the identity. The k-step heads'
input network F (mop.models.horizons) reads h_t and the raw future inputs u. `predict_distribution` raises
MopError for the mean readout (it has no variance). Registered as arch "gpt".

Streaming (`init_cache` / `step`): one new input per call: the front end's running features
(mop.models.features.FeatureState) and the body's circular KV cache of `context` slots per layer, so every
step costs O(context) however long the stream runs.
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

import dataclasses

from torch import Tensor, nn

from mop.config import ModelConfig
from mop.models.features import FeatureState, gap_positions
from mop.models.frontend import FeatureFrontEnd
from mop.models.gpt_body import GPTBody, KVCache
from mop.models.heads import check_dims, require_gaussian
from mop.models.horizons import add_future_inputs, future_head, horizon_loss, stack_heads
from mop.models.interface import LearnedModel
from mop.models.registry import register_model


@dataclasses.dataclass
class StreamCache:
    """The model's stream state: the body's KV cache and the front end's running features."""

    kv: KVCache
    features: FeatureState


@register_model("gpt", predictor="mop")
class Transformer(GPTBody, LearnedModel):
    """The GPT-2 body (its parameters at the top level: read_in, wpe, blocks, ln_f, read_out, future_head)
    wrapped by the feature front end `self.front_end`, which holds no parameters. The raw-input methods
    (forward, predict_distribution, forecast_heads, loss, init_cache / step_distribution) encode, run the
    body and decode; prefill / branch are the body's own (mop.models.rollout uses them only when the front
    end reads no features, where encode is the identity)."""

    context_limited = True  # at most cfg.context inputs per forward (LearnedPredictor windows longer ones)
    supports_stream = True  # the rolling KV cache: equal to forward inside the context
    supports_branch = True  # prefill / branch (mop.models.rollout), unless it reads features
    branchable_state = False
    has_direct_heads = True
    supports_features = True  # model.input_scale / rls_order / arx_order (mop.models.features)

    def __init__(self, cfg: ModelConfig) -> None:
        check_dims(cfg)
        front_end = FeatureFrontEnd(cfg)
        super().__init__(cfg, front_end.input_dim)
        self.front_end = front_end
        self.future_head = future_head(cfg)  # k-step heads on a system with inputs (mop.models.horizons)
        if cfg.rls_order > 0:  # the read-out predicts the residual on RLS: start as the RLS predictor
            nn.init.zeros_(self.read_out.weight)

    @property
    def reads_features(self) -> bool:
        """The running scale, record normalisation or RLS / ARX feature is on (mop.models.features)."""
        return self.front_end.reads_features

    def _outputs(
        self, inputs: Tensor, last: bool = False, future: Tensor | None = None, fitted: Tensor | None = None
    ) -> tuple[Tensor, Tensor | None, Tensor | None]:
        """inputs (B, T, d_in) -> one-step mean (B, T, m), var (B, T, m)|None and the k-step heads' means
        (B, T, K-1, m)|None, in the inputs' units (T = 1: last). future: the k-step heads' future inputs
        (mop.models.horizons.add_future_inputs). The front end decodes every head (a k-step head predicts
        its residual on the one-step feature). fitted (B, d, m)|None: each record's feature coefficients
        (FeatureFrontEnd.encode)."""
        x, frame = self.front_end.encode(inputs, fitted)  # (B, T, d_in + extra)
        frame = frame.last() if last else frame
        h = self.hidden(x, last)
        mu, var, later = self.heads(h)
        later = add_future_inputs(self.future_head, later, h, inputs, self.cfg, future, last)
        return (*self.front_end.decode(frame, mu, var), self.front_end.decode_heads(frame, later))

    def forecast_heads(self, inputs: Tensor, last: bool = False, future: Tensor | None = None) -> Tensor:
        """inputs (B, T, d_in) -> (B, T, K, m): [:, t, k-1] is head k's mean of y_{t+k} from z_0..z_t and
        u_{t+1}..u_{t+k-1} (k = 1 is forward's prediction); last: the last position's only (B, 1, K, m).
        future (B, T or 1, K-1, k): those future inputs (default: the inputs' own, shifted)."""
        mu, _, later = self._outputs(inputs, last, future)
        return stack_heads(mu, later)

    def forward(self, inputs: Tensor, last: bool = False) -> Tensor:
        """inputs (B, T, d_in) -> mean predictions (B, T, m); position t predicts y_{t+1}.
        last: the last position's only (B, 1, m)."""
        return self._outputs(inputs, last)[0]

    def predict_distribution(self, inputs: Tensor, last: bool = False) -> tuple[Tensor, Tensor]:
        """Gaussian readout: (mean, var) each (B, T, m), (B, 1, m) if last. MopError for readout 'mean'."""
        require_gaussian(self.cfg)
        return self._outputs(inputs, last)[:2]

    def loss(self, inputs: Tensor, targets: Tensor, fitted: Tensor | None = None) -> Tensor:
        """MSE (readout 'mean') or mean Gaussian NLL (readout 'gaussian'); targets (B, T, m). With k-step
        heads the mean over k of each head's loss (mop.models.heads.horizon_loss). fitted (B, d, m)|None:
        each record's feature coefficients fitted on its estimation record (train.context_prefix)."""
        cfg = self.cfg
        gaps = gap_positions(inputs, cfg)
        outputs = self._outputs(inputs, fitted=fitted)
        return horizon_loss(*outputs, targets, cfg.observation_mask, cfg.horizon_loss, gaps)

    # ---- streaming ----
    def init_cache(self, batch_size: int) -> StreamCache:
        """An empty stream state for batch_size systems: the body's KV cache and the front end's features."""
        kv = self.init_kv(batch_size)
        return StreamCache(kv, self.front_end.start(batch_size, kv.k.device, kv.k.dtype))

    def step_distribution(self, z: Tensor, cache: StreamCache) -> tuple[Tensor, Tensor | None]:
        """One input z_t (B, d_in) -> (mean, var|None) of y_{t+1}, each (B, m); updates `cache` in place."""
        x, frame = self.front_end.encode_step(cache.features, z)  # (B, 1, d_in + extra)
        mu, var, _ = self.heads(self.step_hidden(x, cache.kv))  # (B, 1, m) each
        mu, var = self.front_end.decode(frame, mu, var)
        return mu[:, 0], None if var is None else var[:, 0]
