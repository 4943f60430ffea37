"""model.position_loss = "balanced": the one-step loss keeps its value (the MSE) and scales each position's
gradient by mean / its MSE (mop.models.heads.balanced_mean), for both architectures, with gaps and k-step
heads."""

import pytest
import torch

from mop.config import ModelConfig
from mop.errors import MopError
from tests.test_rollout import CONTEXT, random_model, random_trajectories


def _inputs_targets(seed: int = 0, gaps: bool = False):
    traj = random_trajectories(4, CONTEXT, 0, seed=seed + 1)
    z, targets = traj.model_inputs()[:, :-1], traj.y[:, 1:].clone()
    if gaps:  # the observation-mask layout [y zero-filled, observed]; a few outputs missing
        seen = torch.rand(targets.shape, generator=torch.Generator().manual_seed(seed)) > 0.3
        y_in = traj.y[:, :-1]
        seen_in = torch.ones_like(y_in, dtype=torch.bool)
        seen_in[:, 1:] = seen[:, :-1]
        z = torch.cat([torch.where(seen_in, y_in, 0.0), seen_in.to(y_in.dtype)], -1)
        targets[~seen] = float("nan")
    return z, targets


@pytest.mark.parametrize("arch", ["gpt", "gru"])
@pytest.mark.parametrize("gaps", [False, True])
def test_balanced_positions_keep_the_mse_and_scale_each_positions_gradient(arch, gaps):
    """The value is mean_t L_t (L_t the MSE over the measured entries at position t); the gradient is
    mean(L) / T * sum_t grad(L_t) / L_t, each L_t's gradient written out by autograd on its own."""
    options = {"observation_mask": True} if gaps else {}
    model = random_model(arch, "learned", "mean", 0, position_loss="balanced", **options)
    z, targets = _inputs_targets(gaps=gaps)
    params = list(model.parameters())
    loss = model.loss(z, targets)
    grads = torch.autograd.grad(loss, params)
    mu = model(z)
    seen = ~torch.isnan(targets)
    per_t = [((mu[:, t] - targets[:, t].nan_to_num()) ** 2 * seen[:, t]).sum() / seen[:, t].sum() for t in
             range(targets.shape[1])]  # fmt: skip
    level = float(sum(per_t).detach()) / len(per_t)
    torch.testing.assert_close(loss.detach(), torch.tensor(level, dtype=torch.float64))
    if not gaps:  # every position has the same count: the mean over positions is the plain MSE
        torch.testing.assert_close(loss.detach(), ((mu - targets) ** 2).mean().detach())
    want = [torch.zeros_like(p) for p in params]
    for L in per_t:
        for w, g in zip(want, torch.autograd.grad(L, params, retain_graph=True), strict=True):
            w += level / len(per_t) * g / float(L.detach())
    for g, w in zip(grads, want, strict=True):
        torch.testing.assert_close(g, w, rtol=1e-5, atol=1e-9)  # the read-out is float32


def test_balanced_positions_differ_from_the_plain_mse_gradient():
    """The weighting changes the gradient (so the option does something): against position_loss 'mean' on
    the same weights and data, the same value, a different gradient."""
    z, targets = _inputs_targets()
    plain, balanced = (
        random_model("gpt", "learned", "mean", 0, position_loss=w) for w in ("mean", "balanced")
    )
    lp, lb = plain.loss(z, targets), balanced.loss(z, targets)
    torch.testing.assert_close(lp, lb)
    gp, gb = (torch.autograd.grad(loss, list(m.parameters())) for loss, m in ((lp, plain), (lb, balanced)))
    assert max(float((a - b).abs().max()) for a, b in zip(gp, gb, strict=True)) > 1e-3


def test_position_loss_settings_are_checked():
    with pytest.raises(MopError, match="model.position_loss must be 'mean' or 'balanced'"):
        ModelConfig(position_loss="late")
    with pytest.raises(MopError, match="use model.readout='mean'"):
        ModelConfig(position_loss="balanced", readout="gaussian")
