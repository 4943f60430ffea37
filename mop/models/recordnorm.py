"""Per-record causal normalisation (model.record_norm = "causal"): every record is read in its own units.

Each output and input channel c of z_t = [y_t, u_t] is normalised by its running mean and standard deviation
over the steps read so far (position t sees z_0..z_t only, so the model stays causal):

    mean_t = (1 / n_t) sum_{s <= t} z_s,   std_t = sqrt((1 / n_t) sum_{s <= t} (z_s - mean_t)^2),
    zn_t = (z_t - mean_t) / std_t   (0 where std_t = 0: a channel constant so far, e.g. t = 0),

n_t counting the measured steps of an output channel (a missing output, model.observation_mask, is left out
and reads 0). The network's mean read-out o_t comes back in the record's units as yhat_{t+1} = b_t +
std_t(y) o_t, b_t = mean_t(y) (or the RLS / ARX feature r_{t+1}, which the network also reads normalised by
mean_t(y), std_t(y)); a channel with std_t = 0 predicts b_t. So for a > 0, c > 0 the map y -> a y + b,
u -> c u + d gives predictions a yhat + b (exactly without the RLS feature, whose ridge prior P_0 = I is not
scale-free; nearly with it): a model trained on one class predicts any record of it in the record's units,
as Forgione et al.'s class models do with each sequence normalised (theirs over the whole sequence).

The sums run from the first value (z_s - z_0), in float64, so a large offset costs no precision. Streaming
(RecordStats) keeps the sums of the whole stream; a sliding window restarts them with each window, as the
other features (mop.models.features).
"""

from __future__ import annotations

import torch
from torch import Tensor


def running_moments(z: Tensor, seen: Tensor | None = None, prior_steps: int = 0) -> tuple[Tensor, Tensor]:
    """Causal per-channel (mean, std), each (B, T, d) float64, of z (B, T, d) over steps 0..t; seen (B, T, d)
    bool (None: all) leaves out the unmeasured entries (a channel with none measured yet: mean 0, std 0).
    prior_steps n_0 > 0 (model.record_prior_steps): the sums start from n_0 pseudo-steps of mean 0 and
    variance 1, mean_t = sum z / (n_t + n_0), std_t^2 = (sum z^2 + n_0) / (n_t + n_0) - mean_t^2 (a channel
    with none measured yet: mean 0, std 1)."""
    z = z.double()
    w = torch.ones_like(z) if seen is None else seen.double()
    ref = _first_seen(z, w)  # (B, 1, d)
    dev = torch.where(w > 0, z - ref, torch.zeros_like(z))  # (B, T, d), 0 where unmeasured
    return _moments(ref, w.cumsum(1), dev.cumsum(1), (dev**2).cumsum(1), prior_steps)


def _moments(ref: Tensor, n: Tensor, s1: Tensor, s2: Tensor, prior_steps: int) -> tuple[Tensor, Tensor]:
    """(mean, std) from the first values ref, the counts n and the sums s1, s2 of z - ref; the prior's
    pseudo-steps (mean 0, variance 1) are, about ref, of mean -ref and second moment 1 + ref^2."""
    if prior_steps:
        n, s1, s2 = n + prior_steps, s1 - prior_steps * ref, s2 + prior_steps * (1.0 + ref**2)
    n = n.clamp_min(1.0)
    m1, m2 = s1 / n, s2 / n
    return ref + m1, (m2 - m1**2).clamp_min(0.0).sqrt()


def _first_seen(z: Tensor, w: Tensor) -> Tensor:
    """(B, 1, d): each channel's first measured value (0 if none)."""
    first = w.cumsum(1).eq(1) & (w > 0)  # (B, T, d): True at the first measured step
    return torch.where(first, z, torch.zeros_like(z)).sum(1, keepdim=True)


def normalise(z: Tensor, mean: Tensor, std: Tensor) -> Tensor:
    """(z - mean) / std, 0 where std = 0; in z's dtype."""
    safe = torch.where(std > 0, std, torch.ones_like(std))
    return torch.where(std > 0, (z.double() - mean) / safe, torch.zeros_like(safe)).to(z.dtype)


class RecordStats:
    """running_moments one step at a time (streaming): the first value and the running sums per channel."""

    def __init__(self, batch_size: int, dim: int, device: torch.device, prior_steps: int = 0) -> None:
        f64 = dict(device=device, dtype=torch.float64)
        self.prior_steps = prior_steps
        self.ref = torch.zeros(batch_size, dim, **f64)
        self.n, self.s1, self.s2 = (torch.zeros(batch_size, dim, **f64) for _ in range(3))

    def update(self, z: Tensor, seen: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """z_t (B, d), seen (B, d) bool|None -> (mean_t, std_t) each (B, d) float64."""
        z = z.double()
        w = torch.ones_like(z) if seen is None else seen.double()
        self.ref = torch.where((self.n == 0) & (w > 0), z, self.ref)
        dev = torch.where(w > 0, z - self.ref, torch.zeros_like(z))
        self.n, self.s1, self.s2 = self.n + w, self.s1 + dev, self.s2 + dev**2
        return _moments(self.ref, self.n, self.s1, self.s2, self.prior_steps)
