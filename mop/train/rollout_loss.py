"""The simulation loss by rollout (train.rollout_after = c > 0): each training window is simulated as the
model is used in free run, and the loss is that simulation's error.

A window holds the model inputs z_0..z_{T-1} (z_t = [y_t, u_t], the model's units) and the targets
y_1..y_T. The model reads the first c measured outputs; from there each prediction is fed back as the next
input's output: position t reads z'_t = [yhat_t, u_t] for t >= c, where yhat_t is the model's output at
position t - 1 of the inputs z_0..z_{c-1}, z'_c..z'_{t-1}. The loss is the mean squared error of
yhat_c..yhat_T against y_c..y_T, with the gradient through every fed-back prediction (backpropagation
through the rollout). Inside the model's context this is exactly what the learned predictor's simulate
(mop.models.predictor.LearnedPredictor) computes after c measured outputs ("rollout" forecasts: the
feature reads the fed-back outputs as it reads measured ones), so what is trained is what is used
(tests/test_rollout_loss.py checks that equality).

Where the one-step loss (mop.models.transformer.Transformer.loss) reads every measured output, this one
reads c per window, so one step costs about T - c forward passes of windows up to T long. It is the loss
of the long free runs the field's benchmarks score (SUBNET, deep LRU and dynoNet train on it as well);
train.rollout_share trains that share of the steps on it (the last ones), the others one step ahead.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from mop.config import RunConfig
from mop.errors import MopError


def rollout_predictions(model: nn.Module, inputs: Tensor, measured: int, output_dim: int) -> Tensor:
    """The free run of `model` over inputs (B, T, d_in) after `measured` = c measured outputs, the first
    output_dim channels of z_t being y_t: (B, T - c + 1, m), row j predicting y_{c+j} (the targets' row
    c - 1 + j). Differentiable through the fed-back predictions."""
    T = inputs.shape[1]
    if not 1 <= measured <= T:
        raise MopError(f"train.rollout_after must be in [1, train.horizon = {T}], got {measured}")
    # a context-limited model (the transformer) computes the last position only on request
    last = getattr(model, "context_limited", False)
    z = inputs[:, :measured]
    predictions = []
    for t in range(measured, T + 1):
        y_hat = model(z, last=True)[:, 0] if last else model(z)[:, -1]  # (B, m): y_t from z_0..z_{t-1}
        predictions.append(y_hat)
        if t < T:
            fed = torch.cat([y_hat, inputs[:, t, output_dim:]], dim=-1)  # z'_t = [yhat_t, u_t]
            z = torch.cat([z, fed[:, None]], dim=1)
    return torch.stack(predictions, dim=1)


def rollout_loss(model: nn.Module, inputs: Tensor, targets: Tensor, measured: int) -> Tensor:
    """Mean squared error of the free run after `measured` outputs (rollout_predictions) against targets
    (B, T, m) = y_1..y_T: over y_c..y_T."""
    m = targets.shape[-1]
    predicted = rollout_predictions(model, inputs, measured, m)
    return torch.mean((predicted - targets[:, measured - 1 :]) ** 2)


class RolloutLoss(nn.Module):
    """forward(inputs, targets) = rollout_loss(model, inputs, targets, measured), beside the one-step
    mop.train.optim.LossModule (not compiled: the rollout's length varies with nothing but c)."""

    def __init__(self, model: nn.Module, measured: int) -> None:
        super().__init__()
        self.model, self.measured = model, measured

    def forward(self, inputs: Tensor, targets: Tensor, *fitted: Tensor) -> Tensor:
        return rollout_loss(self.model, inputs, targets, self.measured)


def rollout_start(config: RunConfig) -> int | None:
    """The first step (0-based) trained on the rollout loss: the last train.rollout_share of the steps;
    None without train.rollout_after."""
    t = config.train
    return None if t.rollout_after <= 0 else t.steps - max(1, round(t.rollout_share * t.steps))


def check_rollout(config: RunConfig) -> None:
    """One-line MopError where train.rollout_after cannot serve the run: it feeds back mean predictions
    into the outputs' channels, so the model reads no observation mask, and it is a loss of its own, not
    combined with the dropped outputs of train.simulate_after or the k-step heads. (That it leaves a simulated
    step, train.rollout_after < train.horizon, the config checks.)"""
    t, m = config.train, config.model
    if t.rollout_after <= 0:
        return
    if m.observation_mask:
        raise MopError(
            "train.rollout_after feeds the model's predictions back as outputs; it needs "
            "model.observation_mask=false (for a simulation loss with a mask use train.simulate_after)"
        )
    if t.simulate_after > 0 or m.horizons > 1:
        raise MopError(
            "train.rollout_after is a loss of its own: leave train.simulate_after at 0 and model.horizons "
            "at 1"
        )
