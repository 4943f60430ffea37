"""MOP with missing outputs: drop-out masks, the loss on measured targets only, the mask input layout (added
only when training drops outputs), streaming and forecasts with gaps, resume with drop-outs, and a model
trained without drop-outs refusing gaps in one line."""

import dataclasses
import json

import numpy as np
import pytest
import torch

import mop.train as mt
from mop.checkpoint import load_tensors
from mop.config import RunConfig, TrainConfig, apply_overrides
from mop.errors import MopError
from mop.missing import drop_mask, drop_outputs, masked_inputs
from mop.models.heads import prediction_loss
from mop.runs import load_predictor
from mop.train.data import with_drop_outs
from tests.reference import interrupted_and_resumed, linear_traj

pytestmark = pytest.mark.usefixtures("one_thread")

TINY = [
    "system.output_dim=2",
    "system.state_dim=4",
    "model.num_layers=1",
    "model.width=16",
    "model.num_heads=2",
    "model.context=12",
    "train.horizon=12",
    "train.batch_size=8",
    "train.steps=6",
    "train.log_every=2",
    "train.checkpoint_every=2",
    "train.device=cpu",
    "train.compile=off",
    "train.deterministic=true",
    "train.num_source_systems=0",
]
DROPS = ["train.missing_rate=0.3", "train.missing_burst_rate=0.05", "train.missing_burst_length=3"]


@pytest.fixture(scope="module")
def masked_run(tmp_path_factory):
    config = apply_overrides(RunConfig(), [*TINY, *DROPS])
    return mt.train(config, tmp_path_factory.mktemp("masked") / "run", progress=False)


def gappy(traj, rate=0.3, seed=1):
    return dataclasses.replace(traj, y=drop_outputs(traj.y, drop_mask(tuple(traj.y.shape), rate, gen(seed))))


def gen(seed):
    return torch.Generator().manual_seed(seed)


def test_masked_loss_is_the_mean_over_measured_targets():
    g = gen(0)
    mu = torch.randn(3, 7, 2, generator=g).requires_grad_()
    var = torch.rand(3, 7, 2, generator=g) + 0.1
    y = torch.randn(3, 7, 2, generator=g)
    drop = torch.rand(3, 7, 2, generator=g) < 0.4
    y_gaps = torch.where(drop, float("nan"), y)
    seen = (~drop).numpy()
    sq = ((mu.detach() - y) ** 2).numpy()
    nll = (0.5 * (torch.log(2 * np.pi * var) + (y - mu.detach()) ** 2 / var)).numpy()
    loss = lambda v, y: float(prediction_loss(mu, v, y, masked=True).detach())  # noqa: E731
    assert loss(None, y_gaps) == pytest.approx(sq[seen].mean(), rel=1e-6)
    assert loss(var, y_gaps) == pytest.approx(nll[seen].mean(), rel=1e-6)
    prediction_loss(mu, var, y_gaps, masked=True).backward()
    assert torch.isfinite(mu.grad).all() and (mu.grad[drop] == 0).all() and (mu.grad[~drop] != 0).all()
    # without gaps the masked loss is the plain one
    assert loss(None, y) == pytest.approx(float(prediction_loss(mu, None, y).detach()))


def test_drop_mask_rate_bursts_and_seed():
    shape = (400, 51, 5)
    drop = drop_mask(shape, 0.3, gen(0))
    n = drop[:, 1:].numel()
    assert abs(float(drop[:, 1:].float().mean()) - 0.3) < 4 * np.sqrt(0.3 * 0.7 / n)  # 4 sigma
    assert not drop[:, 0].any() and torch.equal(drop, drop_mask(shape, 0.3, gen(0)))
    bursts = drop_mask(shape, 0.0, gen(1), burst_rate=0.05, burst_length=4)
    whole = bursts.all(-1)
    assert torch.equal(bursts.any(-1), whole)  # bursts take every channel
    # every run of missing steps lasts at least 4 steps, unless cut by the end or by keeping y_0
    for row in whole[:50].numpy().astype(int):
        edges = np.flatnonzero(np.diff(np.r_[0, row, 0]))
        for start, stop in zip(edges[::2], edges[1::2], strict=True):
            assert stop - start >= 4 or stop == len(row) or start == 1
    expected = 1 - (1 - 0.05) ** 4  # P(a step lies in a burst) away from the start
    assert abs(float(whole[:, 10:].float().mean()) - expected) < 0.02
    assert not drop_mask(shape, 0.0, gen(0)).any()


def test_masked_inputs_layout():
    z = torch.tensor([[[1.0, float("nan"), 5.0], [float("nan"), 2.0, 6.0]]])  # m = 2, k = 1
    out = masked_inputs(z, 2)
    assert torch.equal(out, torch.tensor([[[1.0, 0.0, 5.0, 1.0, 0.0], [0.0, 2.0, 6.0, 0.0, 1.0]]]))


def test_drop_outs_hit_input_and_target_alike():
    y = torch.randn(4, 9, 2, generator=gen(2))
    u = torch.randn(4, 9, 1, generator=gen(3))
    inputs = torch.cat([y[:, :-1], u[:, :-1]], -1)
    cfg = TrainConfig(missing_rate=0.4)
    z, targets = with_drop_outs(inputs, y[:, 1:], cfg, gen(4))
    assert z.shape == (4, 8, 5)
    torch.testing.assert_close(z[:, 1:, 3:5], (~torch.isnan(targets[:, :-1])).float())  # same y_t
    assert torch.equal(z[:, :, 2:3], u[:, :-1]) and (z[:, :, :2][z[:, :, 3:5] == 0] == 0).all()


def test_mask_channel_only_when_training_drops_outputs(tiny_run, masked_run):
    plain = json.loads((tiny_run / "config.json").read_text())
    assert "observation_mask" not in plain["model"] and "missing_rate" not in plain["train"]
    assert plain["model"]["input_dim"] == plain["model"]["output_dim"]  # the layout of before: [y]
    masked = json.loads((masked_run / "config.json").read_text())
    assert masked["model"]["observation_mask"] is True and masked["model"]["input_dim"] == 4  # [y, mask]
    assert masked["train"]["missing_rate"] == 0.3


def test_model_without_drop_outs_refuses_gaps_in_one_line(tiny_run):
    traj = gappy(linear_traj(num_systems=2, horizon=10))
    with pytest.raises(MopError, match="trained without them; train one with train.missing_rate") as err:
        load_predictor(tiny_run).predict(dataclasses.replace(traj, y=traj.y.float()))
    assert "\n" not in str(err.value)


def test_masked_model_streams_and_forecasts_with_gaps(masked_run):
    traj = gappy(linear_traj(num_systems=3, horizon=12))
    window, stream = load_predictor(masked_run), load_predictor(masked_run, mode="stream")
    a = window.predict(traj)
    assert torch.isfinite(a).all()
    torch.testing.assert_close(stream.predict(traj), a, rtol=0, atol=1e-5)  # T <= context: the same
    fc = window.forecast(traj, 3)
    torch.testing.assert_close(fc[:, :, 0], a)
    assert torch.isfinite(fc[:, :-2, 1:]).all()
    # a missing entry's value is never read: the prediction is the same whatever was there
    other = traj.y.clone()
    other[torch.isnan(other)] = 123.0
    filled = window.model_inputs(torch.where(torch.isnan(traj.y), float("nan"), other)[:, :-1])
    assert torch.equal(filled, window.model_inputs(traj.y[:, :-1]))
    # with gaps the predictions differ from those on the complete trajectory (the mask is used)
    full = dataclasses.replace(traj, y=linear_traj(num_systems=3, horizon=12).y)
    assert not torch.allclose(window.predict(full), a)


def test_resume_with_drop_outs_equals_uninterrupted(tmp_path, monkeypatch):
    config = apply_overrides(RunConfig(), [*TINY, *DROPS])
    a = mt.train(config, tmp_path / "a", progress=False)
    b = interrupted_and_resumed(config, tmp_path / "b", monkeypatch)
    wa, wb = load_tensors(a / "model.safetensors")[0], load_tensors(b / "model.safetensors")[0]
    assert all(torch.equal(wa[k], wb[k]) for k in wa)


def test_gru_trains_with_drop_outs_and_streams_gaps_exactly(tmp_path):
    config = apply_overrides(RunConfig(), [*TINY, *DROPS, "model.arch=gru", "train.steps=2"])
    run = mt.train(config, tmp_path / "gru", progress=False)
    traj = gappy(linear_traj(num_systems=2, horizon=20))
    a = load_predictor(run).predict(traj)
    assert torch.isfinite(a).all()
    torch.testing.assert_close(load_predictor(run, mode="stream").predict(traj), a, rtol=0, atol=1e-5)
