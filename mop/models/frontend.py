"""The feature front end around a learned model's body: raw model inputs in, predictions out.

    inputs (B, T, d_in) --encode--> body inputs (B, T, d_in + extra) --body--> read-out (B, T, m)
    read-out --decode--> predictions in the inputs' units (B, T, m)

The body is a plain causal sequence model (mop.models.gpt_body); the front end computes the causal features
of mop.models.features (record normalisation, the RLS / ARX / NARX one-step feature, the running scale, the
observation mask's channels) from the raw inputs z_0..z_t and maps the body's output at position t back
through them: yhat_{t+1} = base_t + scale_t out_t (var: scale_t^2 var_t). Position t of the body's inputs
and outputs is position t of the raw inputs, so whatever predicts y_{t+1} before decode still does after.

The batch path (encode, decode) and the streaming path (start, encode_step, decode) give the same body
inputs and frames for the same inputs while the stream is within the context (mop.models.features). The
front end holds no parameters: a model's state_dict is its body's (and heads').
With every feature off (reads_features False) encode returns the inputs themselves and decode the read-out.
"""

from __future__ import annotations

import dataclasses

import torch
from torch import Tensor

from mop.config import ModelConfig
from mop.models.features import (
    FeatureState,
    augment,
    check_features,
    extra_input_dim,
    reads_features,
    restore,
)


@dataclasses.dataclass(frozen=True)
class Frame:
    """What decode needs from encode, per position: scale (B, T, 1) (running scale) or (B, T, m)
    (record_norm), base (B, T, m) (the feature's one-step prediction, or record_norm's running mean); None
    where the front end has none. Position t maps the body's output at t, the prediction of y_{t+1}."""

    scale: Tensor | None = None
    base: Tensor | None = None

    def last(self) -> Frame:
        """The last position's frame only (B, 1, .)."""
        return Frame(*(None if a is None else a[:, -1:] for a in (self.scale, self.base)))


class FeatureFrontEnd:
    """Raw inputs -> body inputs (encode, encode_step) and body outputs -> predictions (decode); see the
    module docstring. Built from the model's config; checks its feature options once."""

    def __init__(self, cfg: ModelConfig) -> None:
        check_features(cfg)
        self.cfg = cfg

    @property
    def input_dim(self) -> int:
        """The body's input width: d_in plus the features' extra channels (mop.models.features)."""
        return self.cfg.input_dim + extra_input_dim(self.cfg)

    @property
    def reads_features(self) -> bool:
        """True when some feature is on (otherwise encode and decode are the identity)."""
        return reads_features(self.cfg)

    def encode(self, inputs: Tensor, fitted: Tensor | None = None) -> tuple[Tensor, Frame]:
        """inputs (B, T, d_in) -> (body inputs (B, T, input_dim), the frame decode maps position t back with);
        position t reads z_0..z_t only. fitted (B, d, m)|None: each record's feature coefficients fitted on
        its estimation record (mop.models.features.augment; training with train.context_prefix)."""
        x, scale, base = augment(inputs, self.cfg, fitted)
        return x, Frame(scale, base)

    def decode(self, frame: Frame, mu: Tensor, var: Tensor | None = None) -> tuple[Tensor, Tensor | None]:
        """The body's one-step mean, var|None (B, T, m) -> those of y_{t+1} in the inputs' units: scale mu +
        base, scale^2 var."""
        return restore(mu, var, frame.scale, frame.base)

    def decode_heads(self, frame: Frame, later: Tensor | None) -> Tensor | None:
        """The k-step heads' means (B, T, K-1, m)|None -> the inputs' units: each head is a residual on the
        same one-step feature, scaled by the same scale."""
        if later is None:
            return None
        scale, base = (None if a is None else a[:, :, None] for a in (frame.scale, frame.base))
        return restore(later, None, scale, base)[0]

    def start(self, batch_size: int, device: torch.device, dtype: torch.dtype) -> FeatureState:
        """An empty stream state for batch_size systems (the running sums and the RLS / ARX fit)."""
        return FeatureState(self.cfg, batch_size, device, dtype)

    def encode_step(self, state: FeatureState, z: Tensor) -> tuple[Tensor, Frame]:
        """One input z_t (B, d_in) -> (body input (B, 1, input_dim), its frame (B, 1, .)); updates state."""
        x, scale, base = state.step(z)
        return x, Frame(scale, base)
