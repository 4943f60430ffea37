"""The read-out shared by every learned model: the last linear layer gives m or 2m numbers per position.

    readout "mean":      yhat = raw                                       loss = MSE
    readout "gaussian":  [mu, s] = raw, var = softplus(s) + 1e-6
                         loss = mean_{t,i} 0.5 [log(2 pi var) + (y - mu)^2 / var]

Every model builds its read-out with readout_dim and splits it with split_readout.

The direct k-step heads (model.horizons) extend this read-out: mop.models.horizons.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor

from mop.config import ModelConfig
from mop.errors import MopError


def check_dims(cfg: ModelConfig) -> None:
    """MopError unless input_dim and output_dim were resolved (> 0) before building a model."""
    if cfg.input_dim <= 0 or cfg.output_dim <= 0:
        raise MopError(
            f"model.input_dim and model.output_dim must be > 0 to build a model, got "
            f"{cfg.input_dim} and {cfg.output_dim}; set them from the system family first"
        )


def readout_dim(cfg: ModelConfig) -> int:
    """Width of the raw read-out: m for readout 'mean', 2m (mean and pre-softplus variance) for 'gaussian'."""
    return cfg.output_dim * (2 if cfg.readout == "gaussian" else 1)


def split_readout(raw: Tensor, readout: str) -> tuple[Tensor, Tensor | None]:
    """Raw read-out (B, T, m or 2m) -> mean (B, T, m), var (B, T, m) or None."""
    raw = raw.float()  # loss and variance in float32 also under bf16 autocast
    if readout == "mean":
        return raw, None
    mu, s = raw.chunk(2, dim=-1)  # (B, T, m) each
    return mu, F.softplus(s) + 1e-6


def require_gaussian(cfg: ModelConfig) -> None:
    """predict_distribution needs a variance: MopError for readout 'mean'."""
    if cfg.readout != "gaussian":
        raise MopError(
            "predict_distribution needs model.readout='gaussian'; this model predicts only the mean"
        )


def prediction_loss(
    mu: Tensor, var: Tensor | None, targets: Tensor, masked: bool = False, gaps: Tensor | None = None
) -> Tensor:
    """MSE when var is None, else mean over all entries of 0.5 [log(2 pi var) + (y - mu)^2 / var].

    masked (models with an observation mask): targets may hold NaN (missing outputs); the mean is over the
    measured entries only (0 when there are none).
    gaps (B, T) bool (model.gap_loss = "balanced", readout "mean"): True where position t reads a missing
    output. The loss is then sqrt(L_gap L_read), the geometric mean of the MSE over those positions (a
    simulated tail) and over the others (one step ahead), so each group's gradient is scaled by 1 / its own
    MSE; where one group has no scored entry, the other's MSE."""
    if masked:
        seen = ~torch.isnan(targets)
        y = torch.where(seen, targets, mu.detach())
        per = (y - mu) ** 2 if var is None else 0.5 * (torch.log(2 * math.pi * var) + (y - mu) ** 2 / var)
        if gaps is not None and var is None:
            return _balanced(per, seen, gaps[..., None].expand_as(seen))
        return (per * seen).sum() / seen.sum().clamp_min(1)
    if var is None:
        return F.mse_loss(mu, targets)
    return 0.5 * (torch.log(2 * math.pi * var) + (targets - mu) ** 2 / var).mean()


def _balanced(per: Tensor, seen: Tensor, gaps: Tensor) -> Tensor:
    """exp of the mean log of per's mean over seen & gaps and over seen & ~gaps, over the non-empty groups
    (no data-dependent branch, so torch.compile keeps one graph)."""
    groups = torch.stack([seen & gaps, seen & ~gaps]).to(per.dtype)  # (2, B, T, m)
    counts = groups.flatten(1).sum(1)  # (2,)
    means = (per * groups).flatten(1).sum(1) / counts.clamp_min(1)
    has = (counts > 0).to(per.dtype)
    log_mean = (has * torch.log(means.clamp_min(1e-30))).sum() / has.sum().clamp_min(1)
    return torch.exp(log_mean) * has.max()  # 0 where nothing is scored
