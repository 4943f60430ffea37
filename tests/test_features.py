"""Model input features (mop.models.features): the running scale and the RLS feature, against plain formulas
and the RLS baseline, streamed equal to the forward, causal, and a save/load round trip."""

import numpy as np
import pytest
import torch

from mop.config import ModelConfig
from mop.errors import MopError
from mop.filters.arx import arx_predict
from mop.filters.rls import rls_predict
from mop.models import build_model
from mop.models.features import SCALE_EPS, rls_next, running_scale
from mop.models.predict import stream

OPTIONS = [
    {"input_scale": "running"},
    {"rls_order": 2},
    {"input_scale": "running", "rls_order": 3},
]


def tiny(**kw) -> ModelConfig:
    base = dict(num_layers=2, num_heads=2, width=16, context=20, input_dim=3, output_dim=2)
    return ModelConfig(**{**base, **kw})


def inputs(B=4, T=20, d=3, seed=0, scale=1.0):
    g = torch.Generator().manual_seed(seed)
    return scale * torch.randn(B, T, d, generator=g, dtype=torch.float64).cumsum(1) / 3


def test_running_scale_is_the_causal_rms():
    y = inputs()[..., :2]
    s = running_scale(y)  # (B, T, 1)
    yn = y.numpy()
    for t in (0, 5, 19):
        expect = np.sqrt(SCALE_EPS + (yn[:, : t + 1] ** 2).mean(axis=(1, 2)))
        np.testing.assert_allclose(s[:, t, 0].numpy(), expect, rtol=1e-12)


def test_rls_feature_is_the_baseline_one_step_ahead():
    """r[:, t] predicts y_{t+1} from y_0..y_t: the RLS baseline's yhat_{t+1} on the full trajectory."""
    y = inputs(T=21)[..., :2]
    r = rls_next(y[:, :-1], 2)  # (B, 20, 2)
    torch.testing.assert_close(r, rls_predict(y, 2)[:, 1:], rtol=0, atol=0)


@pytest.mark.parametrize("options", OPTIONS)
def test_stream_equals_forward(options):
    model = build_model(tiny(**options)).double().eval()
    z = inputs()
    with torch.no_grad():
        full = model(z)
        streamed, _ = stream(model, z)
    torch.testing.assert_close(streamed, full, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("options", OPTIONS)
def test_causal(options):
    model = build_model(tiny(**options)).double().eval()
    z = inputs()
    z2 = z.clone()
    z2[:, 9:] += 5.0
    with torch.no_grad():
        out, out2 = model(z), model(z2)
    assert torch.equal(out[:, :9], out2[:, :9])
    assert (out[:, 9] - out2[:, 9]).abs().max() > 1e-6


@pytest.mark.parametrize("scale", ["none", "running"])
def test_rls_model_starts_as_the_rls_predictor(scale):
    """The read-out (zero at initialisation) predicts the residual on RLS: an untrained model is RLS."""
    model = build_model(tiny(rls_order=2, input_scale=scale)).double().eval()
    z = inputs(T=21)
    with torch.no_grad():
        out = model(z[:, :-1])
    torch.testing.assert_close(out, rls_predict(z[..., :2], 2)[:, 1:], rtol=1e-12, atol=1e-12)


def test_running_scale_is_nearly_scale_equivariant():
    """With the scale divided out, 100 x the inputs give 100 x the outputs, up to the log s channel (which the
    model reads; its read-in weights are zeroed here) and the eps floor (inputs well above it)."""
    model = build_model(tiny(input_scale="running", input_dim=2)).double().eval()
    with torch.no_grad():
        model.read_in.weight[:, 2] = 0.0  # the log s channel
    z = inputs(d=2) + 1.0
    with torch.no_grad():
        torch.testing.assert_close(model(1000 * z), 100 * model(10 * z), rtol=1e-5, atol=1e-4)


def test_gaussian_variance_is_scaled_back():
    model = build_model(tiny(input_scale="running", readout="gaussian", input_dim=2)).double().eval()
    with torch.no_grad():
        model.read_in.weight[:, 2] = 0.0
    z = inputs(d=2) + 1.0
    with torch.no_grad():
        (_, var), (_, var100) = model.predict_distribution(10 * z), model.predict_distribution(1000 * z)
    torch.testing.assert_close(var100, 1e4 * var, rtol=1e-5, atol=1e-6)


def test_config_errors_and_gru_refuses():
    with pytest.raises(MopError, match="input_scale"):
        tiny(input_scale="bogus")
    with pytest.raises(MopError, match="rls_order"):
        tiny(rls_order=-1)
    with pytest.raises(MopError, match="arch 'gpt'"):
        build_model(tiny(arch="gru", rls_order=2))


def test_save_load_round_trip(tmp_path):
    """The options live in the config (config.json), the weights in safetensors: both rebuild the model."""
    from mop.checkpoint import load_model_weights, save_model
    from mop.config import from_dict, to_dict

    cfg = tiny(input_scale="running", rls_order=2)
    torch.manual_seed(0)
    model = build_model(cfg).eval()
    save_model(tmp_path / "model.safetensors", model)
    torch.manual_seed(1)
    again = build_model(from_dict(ModelConfig, to_dict(cfg))).eval()
    load_model_weights(tmp_path / "model.safetensors", again)
    z = inputs().float()
    with torch.no_grad():
        assert torch.equal(again(z), model(z))


def test_arx_feature_is_the_arx_baseline_one_step_ahead():
    """model.arx_order = q: r[:, t] predicts y_{t+1} from y_0..y_t and u_0..u_t, the arx baseline's
    yhat_{t+1} on the full trajectory; an untrained model (zero read-out) is that ARX predictor."""
    z = inputs(T=21, d=4)  # y (2 outputs), u (2 inputs)
    y, u = z[..., :2], z[..., 2:]
    r = rls_next(y[:, :-1], 2, u[:, :-1], 3)
    torch.testing.assert_close(r, arx_predict(y, u, 2, 3)[:, 1:], rtol=0, atol=0)
    model = build_model(tiny(rls_order=2, arx_order=3, input_dim=4)).double().eval()
    with torch.no_grad():
        torch.testing.assert_close(model(z[:, :-1]), r, rtol=1e-12, atol=1e-12)
    assert not torch.allclose(r, rls_next(y[:, :-1], 2))  # the inputs matter


@pytest.mark.parametrize("options", [{"rls_order": 2, "arx_order": 1}, {"rls_order": 1, "arx_order": 3}])
def test_arx_feature_streams_equal_to_the_forward(options):
    model = build_model(tiny(**options, input_dim=4, input_scale="running")).double().eval()
    with torch.no_grad():
        for p in model.parameters():
            p.normal_(0.0, 0.3)
    z = inputs(d=4)
    with torch.no_grad():
        torch.testing.assert_close(stream(model, z)[0], model(z), rtol=1e-9, atol=1e-9)


def test_arx_order_needs_the_rls_feature_and_inputs():
    with pytest.raises(MopError, match="rls_order"):
        tiny(arx_order=2)
    with pytest.raises(MopError, match="no inputs"):
        build_model(tiny(rls_order=2, arx_order=2, input_dim=2))


@pytest.mark.parametrize(
    "options",
    [
        {"rls_order": 2, "rls_offset": True},
        {"rls_order": 2, "arx_order": 2, "rls_offset": True},
        {"rls_order": 3, "arx_order": 1, "rls_offset": True, "input_scale": "running"},
    ],
)
def test_offset_feature_is_arx_with_an_intercept_and_streams_equal(options):
    """model.rls_offset: the untrained model is arx_predict with offset=True (with or without input lags),
    on outputs with an offset (where the constant matters); streaming equals the forward."""
    model = build_model(tiny(**options)).double().eval()
    z = inputs(T=21) + 2.0
    q = options.get("arx_order", 0)
    u = z[..., 2:] if q else None
    expect = arx_predict(z[..., :2], u, options["rls_order"], max(q, 1), offset=True)[:, 1:]
    with torch.no_grad():
        out = model(z[:, :-1])
        streamed, _ = stream(model, z[:, :-1])
    torch.testing.assert_close(out, expect, rtol=1e-10, atol=1e-10)
    torch.testing.assert_close(streamed, out, rtol=1e-9, atol=1e-9)
    without = rls_next(z[:, :-1, :2], options["rls_order"], None if u is None else u[:, :-1], q)
    assert (out - without).abs().max() > 1e-3  # the constant does enter


def test_offset_needs_the_rls_feature():
    with pytest.raises(MopError, match="rls_order > 0"):
        tiny(rls_offset=True)
    with pytest.raises(MopError, match="rls_offset"):
        tiny(rls_order=2, rls_offset="yes")
