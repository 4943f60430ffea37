"""Per-record causal normalisation (model.record_norm = "causal", mop.models.recordnorm): the running moments
against numpy, predictions equivariant to each record's units, streamed equal to the forward, causal."""

import numpy as np
import pytest
import torch

from mop.config import ModelConfig
from mop.errors import MopError
from mop.filters.arx import arx_forecast
from mop.missing import masked_inputs
from mop.models import build_model
from mop.models.features import filled_moments
from mop.models.predict import stream
from mop.models.predictor import LearnedPredictor
from mop.models.recordnorm import RecordStats, running_moments
from mop.systems.base import Trajectories


def tiny(**kw) -> ModelConfig:
    base = dict(num_layers=2, num_heads=2, width=16, context=20, input_dim=2, output_dim=1)
    return ModelConfig(**{**base, "record_norm": "causal", **kw})


def record(B=3, T=20, seed=0) -> torch.Tensor:
    """(B, T, 2) [y, u]: a random walk output and a white input, float64."""
    g = torch.Generator().manual_seed(seed)
    return torch.cat(
        [torch.randn(B, T, 1, generator=g).cumsum(1), torch.randn(B, T, 1, generator=g)], -1
    ).double()


def trained_like(cfg: ModelConfig, seed: int = 0):
    """A float64 model with every weight random (the zero-initialised RLS read-out too)."""
    torch.manual_seed(seed)
    model = build_model(cfg).double().eval()
    with torch.no_grad():
        for p in model.parameters():
            p.normal_(0, 0.3)
    return model


def test_running_moments_are_numpy_mean_and_std_per_prefix():
    z = record() * 100 + 1e4  # an offset far above the spread
    seen = torch.rand(z.shape, generator=torch.Generator().manual_seed(1)) > 0.3
    seen[:, 0] = True
    for mask in (None, seen):
        mean, std = running_moments(z, mask)
        stats = RecordStats(z.shape[0], z.shape[-1], z.device)
        for t in (0, 1, 7, 19):
            for b in range(z.shape[0]):
                for c in range(z.shape[-1]):
                    keep = np.ones(t + 1, bool) if mask is None else mask[b, : t + 1, c].numpy()
                    x = z[b, : t + 1, c].numpy()[keep]
                    assert mean[b, t, c] == pytest.approx(x.mean(), rel=1e-12)
                    assert std[b, t, c] == pytest.approx(x.std(), rel=1e-8, abs=1e-9)
        streamed = [stats.update(z[:, t], None if mask is None else mask[:, t]) for t in range(z.shape[1])]
        torch.testing.assert_close(torch.stack([s[0] for s in streamed], 1), mean, rtol=1e-12, atol=1e-9)
        torch.testing.assert_close(torch.stack([s[1] for s in streamed], 1), std, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize(
    "a, b, c, d", [(1000.0, -5.0, 0.01, 3.0), (1e-3, 1e4, 50.0, -2.0), (1.0, 0.0, 1.0, 7.0)]
)
def test_predictions_are_equivariant_to_the_records_units(a, b, c, d):
    """y -> a y + b, u -> c u + d (a, c > 0): predictions a yhat + b, every position (one forward)."""
    model = trained_like(tiny())
    z = record()
    w = torch.cat([a * z[..., :1] + b, c * z[..., 1:] + d], -1)
    with torch.no_grad():
        torch.testing.assert_close(model(w), a * model(z) + b, rtol=1e-9, atol=1e-9 * (a + abs(b)))


@pytest.mark.parametrize(
    "options",
    [
        {},
        {"rls_order": 3, "arx_order": 2, "rls_offset": True},
        {"rls_order": 3, "arx_order": 2, "rls_p0": 1e4},
        {"rls_order": 3, "arx_order": 2, "rls_p0": 1e4, "residual_scale": "running"},
        {"rls_order": 3, "arx_order": 2, "rls_offset": True, "rls_cubes": 2},  # cubes in the feature's frame
    ],
)
def test_equivariant_through_the_predictor_beyond_the_context_window_and_stream(options):
    """T = 50 > context 20: the sliding window (each window normalised by its own statistics) and the stream
    are both equivariant, and the stream equals the forward inside the context."""
    model = trained_like(tiny(**options))
    z = record(T=51)
    traj = Trajectories(z[..., :1], z[..., 1:])
    moved = Trajectories(300 * z[..., :1] - 40, 0.2 * z[..., 1:] + 9)
    for mode in ("window", "stream"):
        p = LearnedPredictor(model, mode=mode)
        got, want = p.predict(moved)[:, 1:], 300 * p.predict(traj)[:, 1:] - 40
        torch.testing.assert_close(got, want, rtol=1e-9, atol=1e-6)
    with torch.no_grad():
        torch.testing.assert_close(stream(model, z[:, :20])[0], model(z[:, :20]), rtol=1e-9, atol=1e-9)


MASKED = {"rls_order": 2, "arx_order": 2, "rls_offset": True, "observation_mask": True, "input_dim": 3}


@pytest.mark.parametrize(
    "options",
    [
        {},
        {"rls_order": 2, "arx_order": 2, "rls_offset": True},
        {"rls_order": 2, "arx_order": 2, "rls_offset": True, "residual_scale": "running"},
        MASKED,
        {**MASKED, "rls_p0": 1e4},
        {**MASKED, "rls_p0": 1e4, "residual_scale": "running"},
        {**MASKED, "rls_p0": 1e4, "residual_scale": "measured"},
        {**MASKED, "rls_p0": 1e4, "residual_scale": "running", "residual_decay": 0.9},
        {**MASKED, "rls_p0": 1e4, "record_moments": "filled"},
        {**MASKED, "rls_p0": 1e4, "record_moments": "filled", "residual_scale": "measured"},
        {**MASKED, "rls_p0": 1e4, "residual_scale": "measured", "record_prior_steps": 5},
        {"rls_order": 2, "arx_order": 2, "rls_offset": True, "record_prior_steps": 5},
        {"rls_order": 2, "arx_order": 2, "rls_offset": True, "rls_cubes": 2},  # the cubic NARX feature
        {**MASKED, "rls_p0": 1e4, "rls_cubes": 1, "residual_scale": "measured"},
    ],
)
def test_stream_equals_forward_and_is_causal(options):
    """Streamed (one input at a time) equals the forward; with an observation mask also with outputs missing
    from step 12 on (the stream recomputes the feature once a gap has come)."""
    model = trained_like(tiny(**options))
    z = record()
    if options.get("observation_mask"):
        z[:, 12:, 0] = float("nan")
        z = masked_inputs(z, 1)  # [y zero-filled, u, observed]
    z2 = z.clone()
    z2[:, 9:] += 5.0
    with torch.no_grad():
        torch.testing.assert_close(stream(model, z)[0], model(z), rtol=1e-9, atol=1e-9)
        out, out2 = model(z), model(z2)
    assert torch.equal(out[:, :9], out2[:, :9]) and (out[:, 9] - out2[:, 9]).abs().max() > 1e-6


def test_with_the_arx_feature_equivariant_and_a_constant_record_predicts_itself():
    """The ARX feature runs in the frame of the first r + 1 steps, so its ridge prior (P_0 = I) scales with
    the record too: 10 y - 3, 10 u - 3 gives 10 yhat - 3. A record constant so far has std 0: the untrained
    model (any weights) predicts the running mean."""
    model = trained_like(tiny(rls_order=2, arx_order=2, rls_offset=True))
    z = record()
    with torch.no_grad():
        torch.testing.assert_close(model(10 * z - 3), 10 * model(z) - 3, rtol=1e-9, atol=1e-8)
        const = torch.full((2, 6, 2), 4.0, dtype=torch.float64)
        untrained = build_model(tiny()).double().eval()
        torch.testing.assert_close(untrained(const), const[..., :1])  # the running mean, whatever the weights


def test_bad_combinations_are_refused_in_one_line():
    with pytest.raises(MopError, match="record_norm"):
        tiny(record_norm="bogus")
    for kw in ({"input_scale": "running"}, {"readout": "gaussian"}):
        with pytest.raises(MopError, match="record_norm"):
            build_model(tiny(**kw))
    with pytest.raises(MopError, match="arch 'gpt'"):
        build_model(tiny(arch="gru"))


@pytest.mark.parametrize("norm", ["none", "causal"])
def test_masked_arx_feature_across_a_gap_is_the_arx_simulation(norm):
    """With an observation mask, outputs y_c.. missing: the untrained model (zero read-out: the feature) is
    mop.filters.arx's free-run simulation from origin c, in the record's frame (record_norm) or as is. The
    record (seed 2) is one whose free run stays within the model's fill bounds (mop.filters.rls.fill_bounds,
    tests/test_bounded_fill.py); seeds 0 and 1 leave them."""
    options = dict(input_dim=3, observation_mask=True, rls_order=2, arx_order=2, rls_offset=True, context=30)
    cfg = tiny(record_norm=norm, **options)
    model = build_model(cfg).double().eval()
    z, c = record(T=30, seed=2), 12
    y = z[..., :1].clone()
    y[:, c:] = float("nan")
    with torch.no_grad():
        out = model(masked_inputs(torch.cat([y, z[..., 1:]], -1), 1)[:, :-1])  # position t predicts y_{t+1}
    scale = z[:, : cfg.rls_order + 1].std(1, unbiased=False, keepdim=True) if norm == "causal" else 1.0
    shift = z[:, : cfg.rls_order + 1].mean(1, keepdim=True) if norm == "causal" else 0.0
    zs = (z - shift) / scale
    sim = arx_forecast(zs[..., :1], zs[..., 1:], 2, 2, steps=30 - c, origin=c, offset=True)[:, c]  # (B, K, 1)
    sim = sim * (scale[..., :1] if norm == "causal" else 1.0) + (shift[..., :1] if norm == "causal" else 0.0)
    torch.testing.assert_close(out[:, c - 1 :], sim, rtol=1e-9, atol=1e-9)


def test_gap_simulation_beyond_the_context_goes_in_half_overlapping_windows():
    """T = 50 > context 20, simulation from c = 8: y_8..y_20 are the one-window simulation of y_0..y_20;
    every later output is predicted by a window of 20 inputs starting at a multiple of 10 that reads the
    outputs before it as measured (checked against that window's own predict); and the whole simulation is
    equivariant to the record's units."""
    options = dict(input_dim=3, observation_mask=True, rls_order=2, arx_order=2, rls_offset=True)
    model = trained_like(tiny(**options, forecast_mode="gap"))
    z = record(T=51)
    traj = Trajectories(z[..., :1], z[..., 1:])
    p = LearnedPredictor(model)
    sim = p.simulate(traj, 8)  # (B, 43, 1): y_8..y_50
    y = traj.y.clone()
    y[:, 8:] = float("nan")
    torch.testing.assert_close(sim[:, :13], p.predict(Trajectories(y[:, :21], traj.u[:, :21]))[:, 8:])
    filled = torch.cat([traj.y[:, :8], sim], 1)  # y_0..y_50, simulated from 8 on
    for start, new in ((10, range(21, 31)), (20, range(31, 41)), (30, range(41, 51))):
        window = filled[:, start : start + 21].clone()
        window[:, new[0] - start :] = float("nan")
        pred = p.predict(Trajectories(window, traj.u[:, start : start + 21]))
        torch.testing.assert_close(sim[:, new[0] - 8 : new[-1] - 7], pred[:, new[0] - start :])
    moved = p.simulate(Trajectories(50 * traj.y + 7, 3 * traj.u - 1), 8)
    torch.testing.assert_close(moved, 50 * sim + 7, rtol=1e-9, atol=1e-7)


def test_filled_moments_read_the_features_predictions_where_outputs_are_missing():
    """model.record_moments = "filled": the output moments are numpy's running mean and std of y with each
    missing y_t replaced by the feature's prediction of it (the untrained model's own output at t - 1, the
    feature, from a zero read-out). A fine-tuned model (a listed rls_prior: the ARX of its record) that
    simulates a record from step 1 then has a scale from step 3 on, so a network with random weights moves
    its predictions off the feature; with "measured" std is 0 and the network is muted (the feature)."""
    options = dict(MASKED, rls_prior=[0.6, -0.2, 0.5, 0.3, 0.1], context=30)
    z = record(T=30)
    z[:, 1:, 0] = float("nan")  # only y_0 measured: a simulation from step 1
    inputs = masked_inputs(z, 1)
    feature = build_model(tiny(**options)).double().eval()  # zero read-out: the feature's predictions
    with torch.no_grad():
        r = feature(inputs)[..., 0]  # (B, T): r[:, t] predicts y_{t+1}
    _, std = filled_moments(z, z[..., :1], ~torch.isnan(z[..., :1]), r[..., None])
    filled = torch.cat([z[:, :1, 0], r[:, :-1]], 1).numpy()  # y_0, then the feature's y_1, y_2, ..
    want = np.stack([filled[:, : t + 1].std(1) for t in range(30)], 1)
    np.testing.assert_allclose(std[..., 0].numpy(), want, rtol=1e-9, atol=1e-12)
    assert (want[:, 3:] > 1e-3).all()  # the feature repeats y_0 up to r = 2, then simulates
    model = {mode: trained_like(tiny(**options, record_moments=mode)) for mode in ("measured", "filled")}
    with torch.no_grad():
        out = {mode: net(inputs)[..., 0] for mode, net in model.items()}
    torch.testing.assert_close(out["measured"], r, rtol=1e-9, atol=1e-9)  # muted: the feature
    assert (out["filled"][:, 3:] - r[:, 3:]).abs().min() > 1e-6


def test_prior_steps_start_the_moments_from_pseudo_steps_at_mean_0_and_std_1():
    """model.record_prior_steps = n_0: mean_t = sum x / (n_t + n_0), std_t^2 = (sum x^2 + n_0) / (n_t + n_0)
    - mean_t^2 over the measured x of each prefix (numpy), a channel with none measured yet at mean 0 and
    std 1; streamed (RecordStats) alike. Far from unit scale (an offset of 1e4) as in the plain test."""
    n0 = 7
    z = record() * 100 + 1e4
    seen = torch.rand(z.shape, generator=torch.Generator().manual_seed(1)) > 0.3
    seen[0, :5, 0] = False  # a channel with nothing measured for 5 steps
    mean, std = running_moments(z, seen, n0)
    stats = RecordStats(z.shape[0], z.shape[-1], z.device, n0)
    streamed = [stats.update(z[:, t], seen[:, t]) for t in range(z.shape[1])]
    for t in (0, 1, 4, 7, 19):
        for b in range(z.shape[0]):
            for c in range(z.shape[-1]):
                x = z[b, : t + 1, c].numpy()[seen[b, : t + 1, c].numpy()]
                m = x.sum() / (len(x) + n0)
                v = (np.sum(x**2) + n0) / (len(x) + n0) - m**2
                assert mean[b, t, c] == pytest.approx(m, rel=1e-12, abs=1e-12)
                assert std[b, t, c] == pytest.approx(np.sqrt(v), rel=1e-8)
    assert torch.equal(mean[0, :5, 0], torch.zeros(5)) and torch.equal(std[0, :5, 0], torch.ones(5).double())
    torch.testing.assert_close(torch.stack([s[0] for s in streamed], 1), mean, rtol=1e-12, atol=1e-9)
    torch.testing.assert_close(torch.stack([s[1] for s in streamed], 1), std, rtol=1e-9, atol=1e-9)


def test_prior_steps_let_the_network_act_on_a_record_simulated_from_its_start():
    """A fine-tuned class model (a listed rls_prior) simulating a record from step 1 (only y_0 measured):
    without record_prior_steps its output std is 0, so any weights give the feature; with them the record
    is read at the estimation record's scale and the network moves the predictions off the feature."""
    options = dict(MASKED, rls_prior=[0.6, -0.2, 0.5, 0.3, 0.1], context=30)
    z = record(T=30)
    z[:, 1:, 0] = float("nan")
    inputs = masked_inputs(z, 1)
    with torch.no_grad():
        r = build_model(tiny(**options)).double().eval()(inputs)[..., 0]  # zero read-out: the feature
        muted = trained_like(tiny(**options))(inputs)[..., 0]
        acting = trained_like(tiny(**options, record_prior_steps=20))(inputs)[..., 0]
    torch.testing.assert_close(muted, r, rtol=1e-9, atol=1e-9)
    assert (acting - r).abs().min() > 1e-6


def test_prior_steps_need_record_norm():
    with pytest.raises(MopError, match="record_prior_steps"):
        ModelConfig(record_prior_steps=10)
    with pytest.raises(MopError, match="record_prior_steps"):
        tiny(record_prior_steps=-1)
