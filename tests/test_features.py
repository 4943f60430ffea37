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
from mop.models.predictor import stream

OPTIONS = [
    {"input_scale": "running"},
    {"rls_order": 2},
    {"input_scale": "running", "rls_order": 3},
    {"rls_order": 2, "rls_inputs": True},
    {"input_scale": "running", "rls_order": 3, "rls_inputs": True, "rls_offset": True},
    {"rls_order": 2, "rls_offset": True},
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


@pytest.mark.parametrize("offset", [False, True])
def test_arx_model_starts_as_the_arx_predictor(offset):
    """rls_inputs: the feature (and so the untrained model) is ARX(p, p) on y and the input channels after
    it, with a constant regressor under rls_offset."""
    model = build_model(tiny(rls_order=2, rls_inputs=True, rls_offset=offset)).double().eval()
    z = inputs(T=21)
    with torch.no_grad():
        out = model(z[:, :-1])
    expect = arx_predict(z[..., :2], z[..., 2:], 2, 2, offset=offset)[:, 1:]
    torch.testing.assert_close(out, expect, rtol=1e-12, atol=1e-12)
    assert (out - rls_predict(z[..., :2], 2)[:, 1:]).abs().max() > 1e-3  # the inputs do enter


def test_arx_feature_leaves_the_observation_mask_out():
    """With the observation mask the model reads [y, u, mask]: the ARX feature regresses on u only, and
    streaming agrees."""
    cfg = tiny(rls_order=2, rls_inputs=True, observation_mask=True, input_dim=5)  # m = 2, k = 1, mask 2
    model = build_model(cfg).double().eval()
    z = inputs(T=21, d=5)
    z[..., 3:] = 1.0  # everything measured
    with torch.no_grad():
        out = model(z[:, :-1])
        streamed, _ = stream(model, z[:, :-1])
    torch.testing.assert_close(out, arx_predict(z[..., :2], z[..., 2:3], 2, 2)[:, 1:], rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(streamed, out, rtol=1e-9, atol=1e-9)


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
    with pytest.raises(MopError, match="rls_order > 0"):
        tiny(rls_inputs=True)
    with pytest.raises(MopError, match="rls_offset"):
        tiny(rls_order=2, rls_offset="yes")
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
