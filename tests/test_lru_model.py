"""The deep-LRU body in the registry (arch "deep-lru"): its parallel scan equals its step-by-step loop, its
stream equals its forward far beyond any window, and the simulation loss it trains with (a simulated tail
read as missing, train.simulate_after) has the gradient of finite differences and is the error of the gap
simulation it predicts with."""

import pytest
import torch

from mop.config import ModelConfig, TrainConfig
from mop.models import build_model
from mop.models.predictor import LearnedPredictor
from mop.systems.base import Trajectories
from mop.train.data import with_drop_outs


def tiny(**kw) -> ModelConfig:
    base = dict(arch="deep-lru", num_layers=2, width=8, num_heads=2, context=10, input_dim=3, output_dim=2)
    return ModelConfig(**{**base, **kw})


def test_parallel_scan_equals_the_step_by_step_loop():
    torch.manual_seed(0)
    model = build_model(tiny()).double().eval()
    z = torch.randn(3, 37, 3, dtype=torch.float64)  # T not a power of two
    with torch.no_grad():
        torch.testing.assert_close(model(z), model.loop_forward(z), rtol=0, atol=1e-12)


def test_stream_equals_forward_far_beyond_the_context():
    torch.manual_seed(1)
    model = build_model(tiny(readout="gaussian")).eval()
    z = torch.randn(2, 300, 3)  # context 10: the LRU has none
    with torch.no_grad():
        mu, var = model.predict_distribution(z)
        cache = model.init_cache(2)
        steps = [model.step_distribution(z[:, t], cache) for t in range(300)]
    torch.testing.assert_close(torch.stack([s[0] for s in steps], 1), mu, rtol=0, atol=1e-5)
    torch.testing.assert_close(torch.stack([s[1] for s in steps], 1), var, rtol=0, atol=1e-5)


def masked(T: int = 24, c: int = 6, B: int = 3):
    """A tiny double LRU with the observation mask and a batch of windows whose outputs from a random step
    s >= c on are read as missing and scored (train.simulate_after = c): (model, inputs, targets)."""
    torch.manual_seed(2)
    model = build_model(tiny(input_dim=5, observation_mask=True, forecast_mode="gap", num_layers=1)).double()
    g = torch.Generator().manual_seed(3)
    y, u = torch.randn(B, T + 1, 2, generator=g), torch.randn(B, T + 1, 1, generator=g)
    cfg = TrainConfig(horizon=T, simulate_after=c)
    inputs, targets = with_drop_outs(torch.cat([y, u], -1)[:, :-1], y[:, 1:], cfg, g)
    return model, inputs.double(), targets.double()


def test_the_simulation_loss_gradient_equals_finite_differences():
    """Central differences with h = 1e-3 on a float64 model: the read-out rounds to float32 (as under
    autocast, mop.models.heads.split_readout), so the loss carries ~1e-7 of rounding, ~5e-5 on a difference
    quotient; the truncation error is O(h^2) ~ 1e-6. A gradient that misses a path (the scan's decay, the
    masked inputs) is off by the size of the gradient itself."""
    model, inputs, targets = masked()
    model.loss(inputs, targets).backward()
    lru = model.lrus[0]
    for param in (lru.nu_log, lru.theta_log, lru.B_im, lru.C_re, model.read_in.weight, model.glus[0].weight):
        for index in (0, param.numel() - 1):
            analytic = param.grad.flatten()[index].item()
            with torch.no_grad():
                h = 1e-3
                param.view(-1)[index] += h
                up = model.loss(inputs, targets).item()
                param.view(-1)[index] -= 2 * h
                down = model.loss(inputs, targets).item()
                param.view(-1)[index] += h
            assert analytic == pytest.approx((up - down) / (2 * h), rel=1e-3, abs=2e-4)


def test_the_trained_tail_is_the_gap_simulation_it_predicts_with():
    """A window whose outputs from s on are missing: the model's predictions of y_{s+1}.. in training are
    LearnedPredictor.simulate's (forecast_mode "gap") from the same s, over a window 40 times its context."""
    model = build_model(tiny(input_dim=4, output_dim=1, observation_mask=True, forecast_mode="gap")).double()
    g = torch.Generator().manual_seed(4)
    T, s = 400, 7
    y, u = torch.randn(2, T + 1, 1, generator=g).double(), torch.randn(2, T + 1, 2, generator=g).double()
    traj = Trajectories(y, u)
    p = LearnedPredictor(model)
    sim = p.simulate(traj, s)  # (B, T+1-s, 1): y_s..y_T
    seen = (torch.arange(T) < s).double()[None, :, None].expand(2, T, 1)
    z = torch.cat([y[:, :-1] * seen, u[:, :-1], seen], -1)  # [y or 0, u, mask]: as with_drop_outs writes it
    with torch.no_grad():
        trained = p.model(z.to(next(p.model.parameters()).dtype))  # position t predicts y_{t+1}
    torch.testing.assert_close(trained[:, s - 1 :].double(), sim, rtol=0, atol=1e-6)
