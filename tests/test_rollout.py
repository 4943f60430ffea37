"""Fast learned k-step forecasts (mop.models.rollout: prefill + branches, all origins at once), the streamed
and the windowed ones (mop.models.forecast) and simulations (mop.models.simulate) equal the definition
(tests.reference_models: one predict per origin and step, the predictions written over a copy of the
outputs), on random models in float64, inside the context (T <= C), beyond it (T > C) and with more steps
than the context."""

import itertools

import pytest
import torch

from mop.config import ModelConfig
from mop.models import build_model, forecast, rollout
from mop.models.predictor import LearnedPredictor, Normalization
from mop.models.rollout import can_branch
from mop.systems.base import Trajectories
from tests.reference_models import reference_forecast, reference_simulate

CONTEXT = 6
# (T, K): inside (T < C, T = C), beyond (T > C), and K > C (windows of new inputs only)
SHAPES = [(4, 3), (6, 4), (11, 5), (9, 8)]
pytestmark = pytest.mark.usefixtures("one_thread")
CASES = [
    (arch, position, readout, inputs)
    for arch, position, readout, inputs in itertools.product(
        ("gpt", "gru"), ("learned", "rope"), ("mean", "gaussian"), (0, 2)
    )
    if not (arch == "gru" and position == "rope")
]


def random_model(arch: str, position: str, readout: str, inputs: int, seed: int = 0, **options):
    """A float64 model with N(0, 0.3^2) weights (large enough that every attention weight matters);
    options: more ModelConfig fields (observation_mask=True adds the mask's 3 input channels)."""
    torch.manual_seed(seed)
    mask = 3 if options.get("observation_mask") else 0
    cfg = ModelConfig(
        arch=arch,
        num_layers=2,
        num_heads=2,
        width=16,
        context=CONTEXT,
        position=position,
        readout=readout,
        input_dim=3 + inputs + mask,
        output_dim=3,
        **options,
    )
    model = build_model(cfg).double()
    with torch.no_grad():
        for p in model.parameters():
            p.normal_(0.0, 0.3)
    return model


def random_trajectories(num: int, horizon: int, inputs: int, seed: int = 1) -> Trajectories:
    g = torch.Generator().manual_seed(seed)
    y = torch.randn(num, horizon + 1, 3, generator=g, dtype=torch.float64)
    u = torch.randn(num, horizon + 1, inputs, generator=g, dtype=torch.float64) if inputs else None
    return Trajectories(y=y, u=u)


def assert_equal_forecasts(fast: torch.Tensor, slow: torch.Tensor) -> None:
    assert torch.equal(fast.isnan(), slow.isnan())
    torch.testing.assert_close(fast, slow, rtol=0, atol=1e-10, equal_nan=True)


@pytest.mark.parametrize(("arch", "position", "readout", "inputs"), CASES)
@pytest.mark.parametrize(("horizon", "steps"), SHAPES)
def test_fast_forecast_equals_one_forward_per_origin_and_step(
    arch, position, readout, inputs, horizon, steps
):
    model = random_model(arch, position, readout, inputs)
    assert can_branch(model)
    traj = random_trajectories(3, horizon, inputs)
    predictor = LearnedPredictor(model, chunk_size=2)  # two chunks of systems
    assert_equal_forecasts(predictor.forecast(traj, steps), reference_forecast(predictor, traj, steps))


@pytest.mark.parametrize("position", ["learned", "rope"])
def test_stream_mode_rolls_out_from_the_stream_predictions(position):
    """Beyond the context a streaming model's one-step predictions differ from the window's; the forecast
    starts from them (j = 0 is predict) and rolls out with the window."""
    model = random_model("gpt", position, "mean", 2)
    traj = random_trajectories(2, 13, 2)
    stream = LearnedPredictor(model, mode="stream")
    fast = stream.forecast(traj, 5)
    assert_equal_forecasts(fast, reference_forecast(stream, traj, 5))
    window = LearnedPredictor(model).forecast(traj, 5)
    assert (fast[:, CONTEXT + 2 :, 0] - window[:, CONTEXT + 2 :, 0]).abs().max() > 1e-3


@pytest.mark.parametrize("arch", ["gpt", "gru", "deep-lru"])
def test_normalised_model_forecasts_in_data_units(arch):
    model = random_model(arch, "learned", "mean", 2)
    norm = Normalization.from_lists([1.0, -2.0, 0.5], [2.0, 0.5, 3.0], [0.3, -1.0], [1.5, 0.2])
    traj = random_trajectories(2, 10, 2)
    traj.y = traj.y * 2.0 + 1.0
    predictor = LearnedPredictor(model, normalization=norm)
    fast = predictor.forecast(traj, 4)
    assert_equal_forecasts(fast, reference_forecast(predictor, traj, 4))
    torch.testing.assert_close(fast[:, 0, 0], norm.y_mean.expand(2, 3))


def test_float32_model_matches_to_float_rounding():
    model = random_model("gpt", "learned", "mean", 0).float()
    traj = random_trajectories(4, 12, 0)
    traj.y = traj.y.float()
    predictor = LearnedPredictor(model)
    torch.testing.assert_close(
        predictor.forecast(traj, 6),
        reference_forecast(predictor, traj, 6),
        rtol=1e-4,
        atol=1e-5,
        equal_nan=True,
    )


@pytest.mark.parametrize("features", [{}, {"input_scale": "running", "rls_order": 2}])
@pytest.mark.parametrize(("position", "readout"), [("learned", "mean"), ("rope", "gaussian")])
def test_last_only_forward_is_the_full_forwards_last_output(position, readout, features):
    """forward / predict_distribution with last=True (the sliding window's later windows) skip the last
    block's other positions and equal the full forward at the last position."""
    torch.manual_seed(0)
    cfg = ModelConfig(
        num_layers=3, num_heads=2, width=16, context=CONTEXT, position=position, readout=readout,
        input_dim=5, output_dim=3, **features,
    )  # fmt: skip
    model = build_model(cfg).double().eval()
    with torch.no_grad():
        for p in model.parameters():  # not the RLS start's zero read-out
            p.normal_(0.0, 0.3)
    z = torch.randn(4, CONTEXT, 5, dtype=torch.float64)
    with torch.no_grad():
        torch.testing.assert_close(model(z, last=True), model(z)[:, -1:], rtol=0, atol=1e-12)
        if readout == "gaussian":
            for a, b in zip(model.predict_distribution(z, True), model.predict_distribution(z), strict=True):
                torch.testing.assert_close(a, b[:, -1:], rtol=0, atol=1e-12)


@pytest.mark.parametrize("position", ["learned", "rope"])
def test_prefill_continued_from_a_cache_equals_the_whole_windows_prefill(position):
    """A window prefilled, then its last n positions replaced by new inputs through the cache (written in
    place, twice with a shorter prefix the second time, as the forecast does), equals a prefill of the
    whole new window: the last output, and every position's output with last=False."""
    model = random_model("gpt", position, "mean", 2)
    g = torch.Generator().manual_seed(3)
    z = torch.randn(4, CONTEXT, 5, generator=g, dtype=torch.float64)
    with torch.no_grad():
        _, kv = model.prefill(z, last=True)
        cache = [(k.contiguous(), v.contiguous()) for k, v in kv]
        for n, last in ((2, True), (3, False)):
            new = torch.randn(4, n, 5, generator=g, dtype=torch.float64)
            mu, _ = model.prefill(new, last=last, cache=cache, start=CONTEXT - n)
            whole, _ = model.prefill(torch.cat([z[:, : CONTEXT - n], new], dim=1))
            expected = whole[:, -1:] if last else whole[:, CONTEXT - n :]
            torch.testing.assert_close(mu, expected, rtol=0, atol=1e-10)


FEATURES = [
    dict(input_scale="running", rls_order=1),
    dict(rls_order=2, arx_order=1, rls_offset=True),  # the ARX feature reads the inputs' lags
    dict(rls_order=2, observation_mask=True),
]


def feature_model(features: dict, inputs: int) -> torch.nn.Module:
    model = random_model("gpt", "learned", "mean", inputs, **features)
    with torch.no_grad():  # the RLS feature's read-out starts at zero; make the network matter
        model.read_out.weight.normal_(0.0, 0.3)
    return model


@pytest.mark.parametrize("features", FEATURES)
@pytest.mark.parametrize("horizon", [4, CONTEXT - 1, 9])  # inside the context (streamed) and beyond it
def test_a_model_with_input_features_forecasts_as_the_reference(features, horizon):
    """Input features (running scale, RLS / ARX) are functions of the whole window, fed-back inputs
    included, so there is no branch path. Inside the context forecasts and simulations step copies of the
    model's cache (equal to its forward there); beyond it they take the reference path. Both equal the
    references (one forward per origin and step) to float rounding."""
    inputs = 2 if features.get("arx_order") else 0
    model = feature_model(features, inputs)
    assert not can_branch(model)
    traj = random_trajectories(2, horizon, inputs)
    if features.get("observation_mask"):
        traj.y[0, 2, 1] = float("nan")  # a gap the model reads
    predictor = LearnedPredictor(model)
    assert_equal_forecasts(predictor.forecast(traj, 3), reference_forecast(predictor, traj, 3))
    sim, ref = predictor.simulate(traj, 2), reference_simulate(predictor, traj, 2)
    torch.testing.assert_close(sim, ref, rtol=0, atol=1e-10)


@pytest.mark.parametrize("arch", ["gpt", "gru", "deep-lru"])
def test_streamed_simulation_equals_the_reference(arch):
    model = random_model(arch, "rope", "mean", 2)
    traj = random_trajectories(3, CONTEXT if arch == "gpt" else 3 * CONTEXT, 2)
    predictor = LearnedPredictor(model)
    assert predictor.streams_exactly(traj.horizon)
    for context in (1, 3):
        sim = predictor.simulate(traj, context)
        torch.testing.assert_close(sim, reference_simulate(predictor, traj, context), rtol=0, atol=1e-10)


@pytest.mark.parametrize("arch", ["gpt", "gru", "deep-lru"])
@pytest.mark.parametrize("horizon", [CONTEXT - 1, CONTEXT + 3])
def test_every_rollout_path_equals_the_reference(arch, horizon):
    """Each path forecast_path may choose (branch, stream where it is exact, window) gives the reference's
    forecasts, whichever the chooser picks for this model."""
    model = random_model(arch, "learned", "gaussian", 2)
    traj = random_trajectories(2, horizon, 2)
    predictor = LearnedPredictor(model)
    expected = reference_forecast(predictor, traj, 4)
    paths = [forecast.branched_forecast, forecast.windowed_forecast]
    if predictor.streams_exactly(horizon):
        paths.append(forecast.streamed_forecast)
    for path in paths:
        assert_equal_forecasts(path(predictor, traj, 4), expected)


def test_windows_batched_across_prefill_batches(monkeypatch):
    """Beyond the context the windows are prefilled a few starts at a time (here one per batch) and each
    batch's steps read forecasts made in earlier batches: still the reference."""
    monkeypatch.setattr(rollout, "WINDOWS_PER_BATCH", 1)
    model = random_model("gpt", "rope", "mean", 2)
    traj = random_trajectories(2, 15, 2)
    predictor = LearnedPredictor(model)
    assert_equal_forecasts(predictor.forecast(traj, 9), reference_forecast(predictor, traj, 9))
