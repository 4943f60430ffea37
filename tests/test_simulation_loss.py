"""Training for free-run simulation (train.simulate_after = c, model.forecast_mode = "gap"): every training
window drops and scores its outputs from a random step s >= c on, and a model that starts as its ARX feature
(zero read-out) simulates, once trained so, no worse than that feature on held-out systems."""

import pytest
import torch

from mop.config import ModelConfig, RunConfig, SystemConfig, TrainConfig
from mop.models.predictor import LearnedPredictor
from mop.systems import generator, make_family
from mop.train import train_model
from mop.train.data import with_drop_outs


@pytest.fixture(autouse=True)
def _one_thread(one_thread):
    yield


def test_simulated_tail_drops_and_scores_everything_from_a_uniform_start():
    """B = 4000 windows, T = 30, c = 10: y_s..y_T missing in the inputs (mask 0) and kept in the targets,
    nothing before s dropped; s uniform on {10..30}: min 10, max 30, mean 20 within 4 standard errors."""
    B, T, c = 4000, 30, 10
    y = torch.randn(B, T + 1, 1, generator=torch.Generator().manual_seed(0))
    u = torch.randn(B, T + 1, 1, generator=torch.Generator().manual_seed(1))
    cfg = TrainConfig(horizon=T, simulate_after=c)
    z, targets = with_drop_outs(
        torch.cat([y, u], -1)[:, :-1], y[:, 1:], cfg, torch.Generator().manual_seed(2)
    )
    seen = z[..., 2]  # (B, T): the mask of y_0..y_{T-1}
    torch.testing.assert_close(targets, y[:, 1:])  # every target scored, the dropped ones too
    torch.testing.assert_close(z[..., 1:2], u[:, :-1])
    assert torch.equal(z[..., 0] * seen, y[:, :-1, 0] * seen) and torch.equal(
        z[..., 0] * (1 - seen), 0 * seen
    )
    start = torch.where(seen.sum(1) == T, T, seen.argmin(1))  # the first missing step (T: only y_T)
    assert torch.equal(seen, (torch.arange(T)[None] < start[:, None]).float())  # a tail: 1..1 0..0
    assert start.min() == c and start.max() == T
    sd = ((T - c + 1) ** 2 - 1) ** 0.5 / 12**0.5 / B**0.5
    assert abs(start.float().mean() - (c + T) / 2) < 4 * sd
    with pytest.raises(Exception, match="simulate_after"):
        TrainConfig(horizon=T, simulate_after=T + 1)


def simulation_rmse(model, traj, context: int) -> float:
    sim = LearnedPredictor(model).simulate(traj, context)  # (B, T+1-c, m)
    return float(((sim - traj.y[:, context:]) ** 2).mean().sqrt())


@pytest.mark.slow
def test_a_model_trained_for_simulation_simulates_no_worse_than_its_arx_feature(tmp_path):
    """A tiny model with the ARX(2, 2) feature and an intercept (record_norm causal, gap forecasts) trained
    150 steps with train.simulate_after = 30 on noisy low-order lti-siso systems: its simulation of y_40..y_79
    after a context of 40 on 200 held-out systems has an RMSE no larger than the untrained model's (the zero
    read-out: exactly the feature's ARX simulation, tests/test_recordnorm.py)."""
    family = SystemConfig.resolve_class({"family": "lti-siso"})(max_order=2, noise_std=0.2)
    model = ModelConfig(
        num_layers=1, num_heads=2, width=32, context=80, record_norm="causal", rls_order=2, arx_order=2,
        rls_offset=True, observation_mask=True, forecast_mode="gap",
    )  # fmt: skip
    train = TrainConfig(steps=150, batch_size=16, horizon=79, lr=1e-3, simulate_after=30, log_every=50)
    config = RunConfig(system=family, model=model, train=train)
    trained = train_model(config, tmp_path / "run", progress=False)
    untrained = type(trained)(trained.cfg)
    torch.nn.init.zeros_(untrained.read_out.weight)
    torch.nn.init.zeros_(untrained.read_out.bias)
    traj = make_family(family, dtype=torch.float64).generate(200, 79, generator=generator(4242))
    trained, untrained = trained.double(), untrained.double()
    feature, learned = simulation_rmse(untrained, traj, 40), simulation_rmse(trained, traj, 40)
    print(f"simulation RMSE: ARX feature {feature:.4f}, trained {learned:.4f}")
    assert learned <= feature
