"""model.gap_loss = "balanced": the one-step loss as the geometric mean of the MSE over positions that read a
missing output (a simulated tail) and over the others, checked against that definition written out in numpy
from the model's own predictions, for both architectures; "pooled" stays the plain masked MSE."""

import numpy as np
import pytest
import torch

from mop.config import ModelConfig
from mop.errors import MopError
from mop.missing import masked_inputs
from mop.train.data import simulated_tail
from tests.test_recordnorm import trained_like


def _batch(T: int = 30) -> tuple[torch.Tensor, torch.Tensor]:
    """A record with random drop-outs and a simulated tail from a random step, in the trainer's layout:
    (masked inputs (B, T, 3), targets (B, T, 1) with NaN where a target was dropped but not simulated)."""
    g = torch.Generator().manual_seed(3)
    B = 4
    y = torch.randn(B, T + 1, 1, generator=g, dtype=torch.float64).cumsum(1)
    u = torch.randn(B, T, 1, generator=g, dtype=torch.float64)
    dropped = torch.rand(B, T + 1, 1, generator=g) < 0.1
    dropped[:, 0] = False
    tail = simulated_tail(y.shape, 10, g)
    z = torch.cat([torch.where(dropped | tail, torch.nan, y)[:, :-1], u], -1)
    targets = torch.where(dropped & ~tail, torch.nan, y)[:, 1:]
    return masked_inputs(z, 1), targets


@pytest.mark.parametrize("arch", ["gpt", "gru", "deep-lru"])
def test_balanced_loss_is_the_geometric_mean_of_the_two_groups(arch):
    inputs, targets = _batch()
    base = dict(arch=arch, num_layers=1, num_heads=2, width=16, context=30, input_dim=3, output_dim=1)
    losses = {}
    for weighting in ("pooled", "balanced"):
        model = trained_like(ModelConfig(**base, observation_mask=True, gap_loss=weighting))
        with torch.no_grad():
            losses[weighting] = float(model.loss(inputs, targets))
            yhat = model(inputs).numpy()[..., 0]
    y, reads_gap = targets.numpy()[..., 0], inputs.numpy()[..., -1] < 0.5
    scored = ~np.isnan(y)
    sq = np.where(scored, (y - yhat) ** 2, 0.0)
    gap, read = scored & reads_gap, scored & ~reads_gap
    assert gap.sum() > 20 and read.sum() > 20  # both groups present
    mse_gap, mse_read = sq[gap].mean(), sq[read].mean()
    np.testing.assert_allclose(losses["balanced"], np.sqrt(mse_gap * mse_read), rtol=1e-10)
    np.testing.assert_allclose(losses["pooled"], sq[scored].mean(), rtol=1e-10)


def test_balanced_loss_with_one_group_is_its_mse():
    inputs, targets = _batch()
    inputs[..., -1] = 1.0  # every output read as measured: no gap positions
    model = trained_like(
        ModelConfig(
            num_layers=1,
            num_heads=2,
            width=16,
            context=30,
            input_dim=3,
            output_dim=1,
            observation_mask=True,
            gap_loss="balanced",
        )
    )
    with torch.no_grad():
        got, yhat = float(model.loss(inputs, targets)), model(inputs)
    scored = ~torch.isnan(targets)
    np.testing.assert_allclose(got, float(((targets - yhat)[scored] ** 2).mean()), rtol=1e-10)


def test_balanced_loss_needs_the_mask_and_a_mean_read_out():
    with pytest.raises(MopError, match="gap_loss"):
        ModelConfig(gap_loss="balanced")
    with pytest.raises(MopError, match="gap_loss"):
        ModelConfig(gap_loss="balanced", observation_mask=True, readout="gaussian")
