"""Missing outputs: the convention and the seeded drop-outs used in training and in the missing-data tests.

Convention (everywhere in mop): NaN in y[:, t, i] means output channel i was not measured at step t (an empty
CSV cell reads as NaN). Trajectories.observed is the mask (True = measured). Inputs u are always complete.
"""

from __future__ import annotations

import torch
from torch import Tensor


def drop_mask(
    shape: tuple[int, ...],
    rate: float,
    generator: torch.Generator,
    burst_rate: float = 0.0,
    burst_length: int = 5,
    keep_first: bool = True,
) -> Tensor:
    """(B, T+1, m) bool, True where an output is dropped (missing).

    Each entry is dropped independently with probability `rate` (per channel, per step); in addition a burst
    of `burst_length` consecutive steps with every channel missing starts at each step with probability
    `burst_rate`. keep_first: y_0 is never dropped. Draws come from `generator` (its device): same seed,
    same mask; with rate = burst_rate = 0 nothing is drawn.
    """
    B, T1, m = shape
    dev = generator.device
    drop = torch.zeros(shape, dtype=torch.bool, device=dev)
    if rate > 0:
        drop |= torch.rand(shape, generator=generator, device=dev) < rate
    if burst_rate > 0:
        starts = (torch.rand((B, T1), generator=generator, device=dev) < burst_rate).float()  # (B, T+1)
        # a step is inside a burst when a burst started at one of the burst_length steps up to it
        kernel = torch.ones(1, 1, burst_length, device=dev)
        covered = torch.nn.functional.conv1d(starts[:, None], kernel, padding=burst_length - 1)[:, 0, :T1]
        drop |= (covered > 0)[..., None]
    if keep_first:
        drop[:, 0] = False
    return drop


def drop_outputs(y: Tensor, drop: Tensor) -> Tensor:
    """y (B, T+1, m) with the entries where drop (same shape, bool) is True set to NaN (a copy)."""
    return torch.where(drop.to(y.device), torch.full_like(y, float("nan")), y)


def masked_inputs(z: Tensor, output_dim: int) -> Tensor:
    """The input layout of a model with an observation mask: z (B, T, m + k) with NaN in its first m columns
    where an output is missing -> (B, T, m + k + m) [y zero-filled, u, observed as 0/1]."""
    y = z[..., :output_dim]
    seen = ~torch.isnan(y)
    filled = torch.where(seen, y, torch.zeros_like(y))
    return torch.cat([filled, z[..., output_dim:], seen.to(z.dtype)], dim=-1)
