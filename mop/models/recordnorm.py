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


def running_moments(z: Tensor, seen: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """Causal per-channel (mean, std), each (B, T, d) float64, of z (B, T, d) over steps 0..t; seen (B, T, d)
    bool (None: all) leaves out the unmeasured entries (a channel with none measured yet: mean 0, std 0)."""
    z = z.double()
    w = torch.ones_like(z) if seen is None else seen.double()
    ref = _first_seen(z, w)  # (B, 1, d)
    dev = torch.where(w > 0, z - ref, torch.zeros_like(z))  # (B, T, d), 0 where unmeasured
    n = w.cumsum(1).clamp_min(1.0)
    m1, m2 = dev.cumsum(1) / n, (dev**2).cumsum(1) / n
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

    def __init__(self, batch_size: int, dim: int, device: torch.device) -> None:
        f64 = dict(device=device, dtype=torch.float64)
        self.ref = torch.zeros(batch_size, dim, **f64)
        self.n, self.s1, self.s2 = (torch.zeros(batch_size, dim, **f64) for _ in range(3))

    def update(self, z: Tensor, seen: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """z_t (B, d), seen (B, d) bool|None -> (mean_t, std_t) each (B, d) float64."""
        z = z.double()
        w = torch.ones_like(z) if seen is None else seen.double()
        self.ref = torch.where((self.n == 0) & (w > 0), z, self.ref)
        dev = torch.where(w > 0, z - self.ref, torch.zeros_like(z))
        self.n, self.s1, self.s2 = self.n + w, self.s1 + dev, self.s2 + dev**2
        n = self.n.clamp_min(1.0)
        m1, m2 = self.s1 / n, self.s2 / n
        return self.ref + m1, (m2 - m1**2).clamp_min(0.0).sqrt()
