"""A learned predictor's input handling: the affine normalisation of a recorded-data run, and the check
that flags inputs far outside the training data.

A model trained in its family's units (model.output_units / input_units, set by model.features=auto where
the family's signals are far from unit scale) reads y / output_units and u / input_units, and its
predictions are multiplied back (Normalization.of_units, what LearnedPredictor uses when given none).
A model trained on recorded data (`mop train --data`) reads normalised inputs: Normalization maps
z -> (z - z_mean) / z_std before the model (in float64) and the model's mean mu -> mu * y_std + y_mean
(variance var * y_std^2) after it, so predictions are in the data's units.

Inputs far outside what the model was trained on are flagged (once per predictor, mop.models.predict) with
a MopWarning: the root-mean-square of each input channel, in standard deviations of the training inputs from
their mean (`input_stats`, the run's inputs.json; after the normalisation of a recorded-data run, whose
training inputs have mean 0 and std 1), above OOD_RMS = 5. Training data scores 1 by construction. Measured
on the outputs of 1000 systems (T = 50) against a linear-family training set: the noise-shift experiment's
largest test noise (5x the training variance) 2.1, colored noise 2.7, upper-triangular systems 4.0 (all
below, no warning: shifts the experiments study on purpose); a 20000-step random walk is far above.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import torch
from torch import Tensor

from mop.config import ModelConfig
from mop.models.features import input_count

OOD_RMS = 5.0  # warn when an input channel's RMS z-score against the training inputs exceeds this

InputStats = tuple[Sequence[float], Sequence[float]]  # per input channel: training mean, training std


@dataclasses.dataclass(frozen=True)
class Normalization:
    """Per-channel affine scaling, float64: y_mean, y_std (m,) of outputs, u_mean, u_std (k,) of inputs."""

    y_mean: Tensor
    y_std: Tensor
    u_mean: Tensor
    u_std: Tensor

    @classmethod
    def from_lists(
        cls, y_mean: Sequence[float], y_std: Sequence[float], u_mean: Sequence[float], u_std: Sequence[float]
    ) -> Normalization:
        t = lambda v: torch.tensor(list(v), dtype=torch.float64)  # noqa: E731
        return cls(t(y_mean), t(y_std), t(u_mean), t(u_std))

    @classmethod
    def of_units(cls, model: ModelConfig) -> Normalization | None:
        """Reading data in a simulated model's units (model.output_units / input_units, the family's units:
        y / units, u / units, no shift), None where the model has none."""
        if model.output_units is None and model.input_units is None:
            return None
        m, k = model.output_dim, input_count(model)
        y_units = model.output_units or [1.0] * m
        u_units = model.input_units or [1.0] * k
        return cls.from_lists([0.0] * m, y_units, [0.0] * k, u_units)

    def inputs(self, z: Tensor) -> Tensor:
        """z (B, T, m + k) in data units -> normalised, float64."""
        mean = torch.cat([self.y_mean, self.u_mean]).to(z.device)
        std = torch.cat([self.y_std, self.u_std]).to(z.device)
        return (z.double() - mean) / std

    def outputs(self, mu: Tensor, var: Tensor | None) -> tuple[Tensor, Tensor | None]:
        """Normalised mean, var|None (B, T, m) -> data units, float64."""
        mean, std = self.y_mean.to(mu.device), self.y_std.to(mu.device)
        return mu.double() * std + mean, None if var is None else var.double() * std**2

    def output_units(self, y: Tensor) -> Tensor:
        """Outputs y (..., m) in data units (float64) -> the model's normalised units."""
        return (y - self.y_mean.to(y.device)) / self.y_std.to(y.device)


def out_of_range(z: Tensor, input_stats: InputStats | None) -> tuple[int, float] | None:
    """(channel, RMS z-score) of the worst input channel of z (B, T, d_in) when its RMS z-score against
    the training inputs exceeds OOD_RMS; None when it does not, or there is nothing to compare."""
    if input_stats is None or z.numel() == 0:
        return None
    mean, std = (torch.tensor(v, dtype=torch.float64, device=z.device) for v in input_stats)
    if mean.shape[0] != z.shape[-1]:
        return None
    rms = torch.nanmean(((z.double() - mean) / std) ** 2, dim=(0, 1)).sqrt()  # (d_in,); NaN: missing y
    rms = torch.nan_to_num(rms, nan=0.0)  # a channel with no value (y in a free run): not out of range
    worst = int(rms.argmax())
    return (worst, float(rms[worst])) if float(rms[worst]) > OOD_RMS else None
