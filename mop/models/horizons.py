"""Direct k-step heads (model.horizons = K > 1): head k at position t predicts y_{t+k} from z_0..z_t and the
known future inputs u_{t+1}..u_{t+k-1}.

    read-out:  [one-step read-out (m or 2m, mop.models.heads), g_2 .. g_K (m each)] = W_out h_t
    head k:    yhat_{t+k|t} = g_k + F([h_t, u_{t+1}, .., u_{t+k-1}, 0, .., 0, e_k])        (k = 2..K)
    loss:      mean over k = 1..K of head k's loss on y_{t+k} over the positions t <= T - k

F (FutureInputHead, only for systems with inputs u) is a one-hidden-layer GELU MLP shared by the heads: it
reads the final hidden state h_t, the future inputs a head may use (later slots zeroed) and a one-hot e_k
of the head; its last layer starts at zero, so an untrained model's heads are linear in h_t. A model
without inputs has no F. The one-step read-out is unchanged, so everything that reads one-step predictions
(predict, streaming, roll-out forecasts) is the same code.

The k-step heads predict the conditional mean of y_{t+k} directly: nothing predicted is fed back, and on a
nonlinear system a k-step forecast is the predictive mean, not the mean path of a roll-out
(model.forecast_mode = "direct", mop.models.forecast.direct_forecast). This is the
"direct" multi-step strategy of forecasting, beyond the paper (its model has K = 1).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn
from torch.nn import functional as F

from mop.config import ModelConfig
from mop.models.features import input_count
from mop.models.heads import prediction_loss, readout_dim, split_readout


def horizon_dim(cfg: ModelConfig) -> int:
    """Width of the whole read-out: readout_dim plus (horizons - 1) m for the k-step heads."""
    return readout_dim(cfg) + (cfg.horizons - 1) * cfg.output_dim


def split_horizons(raw: Tensor, cfg: ModelConfig) -> tuple[Tensor, Tensor | None, Tensor | None]:
    """Whole read-out (B, T, horizon_dim) -> one-step mean (B, T, m), var|None, and the k-step heads' linear
    part g (B, T, K-1, m) for k = 2..K (None when model.horizons = 1)."""
    width = readout_dim(cfg)
    mu, var = split_readout(raw[..., :width], cfg.readout)
    if cfg.horizons == 1:
        return mu, var, None
    return mu, var, raw[..., width:].to(mu.dtype).unflatten(-1, (cfg.horizons - 1, cfg.output_dim))


def stack_heads(mu: Tensor, later: Tensor | None) -> Tensor:
    """One-step mean (B, T, m) and k-step heads (B, T, K-1, m)|None -> all heads (B, T, K, m)."""
    return mu[:, :, None] if later is None else torch.cat([mu[:, :, None], later], dim=2)


def own_future_inputs(inputs: Tensor, cfg: ModelConfig) -> Tensor:
    """The model inputs' own u channels shifted: (B, T, d_in) -> future_inputs (B, T, K-1, k)."""
    m = cfg.output_dim
    return future_inputs(inputs[..., m : m + input_count(cfg)], cfg.horizons)


def future_inputs(u: Tensor, horizons: int) -> Tensor:
    """u (B, T, k) at positions 0..T-1 -> (B, T, K-1, k): [:, t, j] = u_{t+1+j}, 0 beyond T-1."""
    B, T, k = u.shape
    padded = torch.cat([u, u.new_zeros(B, horizons - 1, k)], dim=1)  # (B, T+K-1, k)
    return padded[:, 1:].unfold(1, horizons - 1, 1)[:, :T].transpose(-1, -2)  # (B, T, K-1, k)


class FutureInputHead(nn.Module):
    """F of the module docstring: (h (B, T, d), future inputs (B, T, K-1, k)) -> (B, T, K-1, m)."""

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        K1, k = cfg.horizons - 1, input_count(cfg)
        self.hidden = nn.Linear(cfg.width + K1 * k + K1, cfg.width)
        self.out = nn.Linear(cfg.width, cfg.output_dim)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)
        # visible[i, j]: head k = i + 2 reads future slot j (u_{t+1+j}) for j <= i, i.e. u_{t+1}..u_{t+k-1}
        self.register_buffer("visible", torch.ones(K1, K1).tril(), persistent=False)

    def forward(self, h: Tensor, future: Tensor) -> Tensor:
        *lead, K1, k = future.shape
        seen = (future[..., None, :, :] * self.visible[:, :, None].to(future)).flatten(
            -2
        )  # (B, T, K-1, K1 k)
        which = torch.eye(K1, dtype=h.dtype, device=h.device).expand(*lead, K1, K1)  # one-hot e_k
        x = torch.cat([h[..., None, :].expand(*lead, K1, h.shape[-1]), seen.to(h.dtype), which], dim=-1)
        return self.out(F.gelu(self.hidden(x)))  # (B, T, K-1, m)


def horizon_loss(
    mu: Tensor,
    var: Tensor | None,
    later: Tensor | None,
    targets: Tensor,
    masked: bool = False,
    weighting: str = "mean",
    gaps: Tensor | None = None,
) -> Tensor:
    """The mean over k = 1..K of the heads' losses L_k: head 1 is prediction_loss(mu, var, targets); head
    k >= 2 (later[:, :, k-2], position t predicting y_{t+k} = targets[:, t+k-1]) is the MSE over the
    positions t <= T-k (heads with k > T have no target and do not count). targets (B, T, m) as for
    prediction_loss; gaps (B, T) bool, head 1's positions that read a missing output (model.gap_loss
    "balanced": prediction_loss weighs them against the others).

    weighting "balanced" (model.horizon_loss): the same value, but each head's gradient is scaled by
    mean(L) / L_k (both held constant), i.e. the gradient of mean(L) * mean_k log L_k: a far horizon's larger
    error no longer outweighs the one-step head's (on the quadrotor L_10 is about 10 L_1)."""
    losses = [prediction_loss(mu, var, targets, masked, gaps)]
    if later is not None:
        T = targets.shape[1]
        for k in range(2, min(later.shape[2] + 1, T) + 1):
            losses.append(prediction_loss(later[:, : T - k + 1, k - 2], None, targets[:, k - 1 :], masked))
    stacked = torch.stack(losses)  # (K,)
    if weighting == "mean" or len(losses) == 1:
        return stacked.mean()
    level = stacked.mean().detach()
    return level * (stacked / stacked.detach().clamp_min(1e-12)).mean()


def future_head(cfg: ModelConfig) -> FutureInputHead | None:
    """The model's F: for k-step heads on a system with inputs u, else None."""
    return FutureInputHead(cfg) if cfg.horizons > 1 and input_count(cfg) > 0 else None


def add_future_inputs(
    head: FutureInputHead | None,
    later: Tensor | None,
    h: Tensor,
    inputs: Tensor,
    cfg: ModelConfig,
    future: Tensor | None = None,
    last: bool = False,
) -> Tensor | None:
    """g + F(h, future inputs) for the k-step heads g (B, T, K-1, m) (g itself without F).
    future (B, T, K-1, k) defaults to the inputs' own u channels shifted (future_inputs; the training
    semantics, exact wherever a target exists); last: h and the result are the last position's only, and so
    must `future` be."""
    if head is None or later is None:
        return later
    if future is None:
        future = own_future_inputs(inputs, cfg)
        future = future[:, -1:] if last else future
    return later + head(h, future)
