"""Gap forecasts (model.forecast_mode = "gap"): a model with an observation mask forecasts y_{t+j} by
reading the future outputs as missing. The batched LearnedPredictor.gap_forecast equals its definition,
one predict per (origin t, step j) on a copy of the data with y_t..y_{t+j-1} set to NaN; and training with
train.score_dropped scores the outputs it drops from the inputs."""

import pytest
import torch

from mop.config import ModelConfig, TrainConfig
from mop.errors import MopError
from mop.models.predictor import LearnedPredictor
from mop.systems.base import Trajectories
from mop.train.data import with_drop_outs
from tests.test_rollout import random_model

pytestmark = pytest.mark.usefixtures("one_thread")


def gap_model(arch: str, inputs: int, seed: int = 0) -> LearnedPredictor:
    """A float64 random model with an observation mask (input width m + k + m) that forecasts by gaps."""
    return LearnedPredictor(
        random_model(arch, "learned", "mean", inputs, seed, observation_mask=True, forecast_mode="gap")
    )


def trajectories(horizon: int, inputs: int, gaps: bool) -> Trajectories:
    g = torch.Generator().manual_seed(1)
    y = torch.randn(5, horizon + 1, 3, generator=g, dtype=torch.float64)
    if gaps:  # the data's own missing outputs stay missing
        y[torch.rand(y.shape, generator=g) < 0.2] = float("nan")
    u = torch.randn(5, horizon + 1, inputs, generator=g, dtype=torch.float64) if inputs else None
    return Trajectories(y=y, u=u)


def by_definition(p: LearnedPredictor, traj: Trajectories, steps: int) -> torch.Tensor:
    B, T1, m = traj.y.shape
    out = traj.y.new_full((B, T1, steps, m), float("nan"))
    for t in range(T1):
        for j in range(min(steps, T1 - t)):
            y = traj.y.clone()
            y[:, t : t + j] = float("nan")
            out[:, t, j] = p.predict(Trajectories(y, traj.u))[:, t + j]
    return out


@pytest.mark.parametrize("arch", ["gpt", "gru", "deep-lru"])
@pytest.mark.parametrize("horizon,steps,inputs,gaps", [(5, 3, 0, False), (11, 4, 2, False), (13, 9, 1, True)])
def test_gap_forecast_equals_one_predict_per_origin_and_step(arch, horizon, steps, inputs, gaps):
    p = gap_model(arch, inputs)
    traj = trajectories(horizon, inputs, gaps)
    fast = p.forecast(traj, steps)
    slow = by_definition(p, traj, steps)
    assert torch.equal(fast.isnan(), slow.isnan())
    torch.testing.assert_close(fast, slow, rtol=0, atol=1e-10, equal_nan=True)
    # the first column is the one-step prediction, and a later step differs from feeding predictions back
    torch.testing.assert_close(fast[:, :, 0], p.predict(traj), equal_nan=True)


def test_gap_simulation_is_the_forecast_from_the_context():
    """Within the model's context (T <= C); beyond it the simulation goes in half-overlapping windows
    (mop.models.simulate.gap_simulation, tests/test_recordnorm.py) and the forecast slides its window."""
    p = gap_model("gpt", 2)
    T = p.cfg.context
    traj = trajectories(T, 2, False)
    sim = p.simulate(traj, 4)  # (B, T+1-c, m): y_4..y_T from y_0..y_3 and the inputs
    f = p.forecast(traj, T - 3)  # f[:, 4, j] forecasts y_{4+j}
    torch.testing.assert_close(sim, f[:, 4], rtol=0, atol=1e-10)


def test_score_dropped_keeps_the_dropped_targets_and_hides_them_from_the_inputs():
    g = torch.Generator().manual_seed(0)
    inputs, targets = torch.randn(4, 30, 3, generator=g), torch.randn(4, 30, 2, generator=g)
    cfg = TrainConfig(missing_burst_rate=0.2, missing_burst_length=4, score_dropped=True)
    z, scored = with_drop_outs(inputs, targets, cfg, torch.Generator().manual_seed(5))
    seen = z[..., 3:]  # (B, T, m) observation mask of the inputs y_0..y_{T-1}
    assert 0 < int((seen == 0).sum()) < seen.numel()
    torch.testing.assert_close(scored, targets)  # every target is scored, dropped or not
    _, unscored = with_drop_outs(
        inputs,
        targets,
        TrainConfig(missing_burst_rate=0.2, missing_burst_length=4),
        torch.Generator().manual_seed(5),
    )
    # without score_dropped, target t (= y_{t+1}) is missing exactly where input t+1 is
    torch.testing.assert_close(unscored[:, :-1].isnan().float(), 1 - seen[:, 1:])


def test_gap_options_are_refused_where_they_cannot_work():
    with pytest.raises(MopError, match="observation_mask"):
        ModelConfig(forecast_mode="gap")
    with pytest.raises(MopError, match="score_dropped"):
        TrainConfig(score_dropped=True)
