"""The model's shape (mop.models.transformer): the GPT-2 body (mop.models.gpt_body) inside the feature front
end (mop.models.frontend). Encode, body, decode composed by hand equal the model's own forward, distribution,
k-step heads and stream; the body streams equal to its own batch path on any inputs; the front end's stream
gives the batch path's body inputs and frames; with the features off it is the identity; it holds no
parameters."""

import pytest
import torch

from mop.config import ModelConfig
from mop.missing import masked_inputs
from mop.models import build_model
from mop.models.gpt_body import GPTBody
from mop.models.horizons import add_future_inputs, stack_heads

CONFIGS = {
    "paper": {},
    "running scale, gaussian": {"input_scale": "running", "readout": "gaussian"},
    "arx, k-step heads": {"rls_order": 2, "arx_order": 2, "horizons": 3},
    "record_norm, mask": {
        "record_norm": "causal",
        "rls_order": 2,
        "arx_order": 2,
        "rls_offset": True,
        "observation_mask": True,
        "residual_scale": "running",
        "input_dim": 5,
    },
}


def model_and_inputs(options: dict, T: int = 16, seed: int = 0) -> tuple[torch.nn.Module, torch.Tensor]:
    """A model of random weights (read-out included, which the RLS feature starts at zero), float64, and
    inputs (3, T, d_in): two outputs y and one input u, with gaps under an observation mask."""
    base = dict(num_layers=2, num_heads=2, width=16, context=20, input_dim=3, output_dim=2)
    cfg = ModelConfig(**{**base, **options})
    torch.manual_seed(seed)
    model = build_model(cfg).double().eval()
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.1 * torch.randn_like(p))
    g = torch.Generator().manual_seed(seed)
    z = torch.randn(3, T, 3, generator=g, dtype=torch.float64).cumsum(1) / 3
    if cfg.observation_mask:
        z[0, 5:8, 0] = float("nan")
        z[2, 11:, :2] = float("nan")
        z = masked_inputs(z, 2)  # [y zero-filled, u, observed]
    return model, z


@pytest.mark.parametrize("options", CONFIGS.values(), ids=CONFIGS.keys())
def test_encode_body_decode_is_the_model(options):
    """front_end.encode -> body.hidden -> body.heads -> front_end.decode equals forward (and the Gaussian
    distribution, the k-step heads) bit for bit, at every position and at the last alone (which is the whole
    window's last position)."""
    model, z = model_and_inputs(options)
    front = model.front_end
    with torch.no_grad():
        for last in (False, True):
            x, frame = front.encode(z)
            frame = frame.last() if last else frame
            h = model.hidden(x, last)
            mu, var, later = model.heads(h)
            later = add_future_inputs(model.future_head, later, h, z, model.cfg, None, last)
            mean, variance = front.decode(frame, mu, var)
            assert torch.equal(mean, model(z, last=last))
            if last:  # the last position of the whole window's predictions
                torch.testing.assert_close(mean, model(z)[:, -1:], rtol=1e-9, atol=1e-9)
            assert torch.equal(
                stack_heads(mean, front.decode_heads(frame, later)), model.forecast_heads(z, last)
            )
            if model.cfg.readout == "gaussian":
                expected = model.predict_distribution(z, last=last)
                assert torch.equal(mean, expected[0]) and torch.equal(variance, expected[1])


@pytest.mark.parametrize("options", CONFIGS.values(), ids=CONFIGS.keys())
def test_stream_composes_as_the_batch_path(options):
    """Inside the context: the front end's encode_step gives encode's body inputs and frames, the body's
    step_hidden gives hidden's states, and the model's step_distribution is their composition."""
    model, z = model_and_inputs(options)
    front = model.front_end
    B, T, _ = z.shape
    with torch.no_grad():
        x, frame = front.encode(z)
        h = model.hidden(x)
        state, kv, cache = front.start(B, z.device, z.dtype), model.init_kv(B), model.init_cache(B)
        for t in range(T):
            x_t, frame_t = front.encode_step(state, z[:, t])
            torch.testing.assert_close(x_t, x[:, t : t + 1], rtol=1e-9, atol=1e-9)
            for got, want in ((frame_t.scale, frame.scale), (frame_t.base, frame.base)):
                assert (got is None) == (want is None)
                if got is not None:
                    torch.testing.assert_close(got, want[:, t : t + 1], rtol=1e-9, atol=1e-9)
            h_t = model.step_hidden(x[:, t : t + 1], kv)  # the body alone, on the batch path's inputs
            torch.testing.assert_close(h_t, h[:, t : t + 1], rtol=1e-9, atol=1e-9)
            mu, var = model.step_distribution(z[:, t], cache)
            mean, variance = front.decode(frame_t, *model.heads(h_t)[:2])
            torch.testing.assert_close(mu, mean[:, 0], rtol=1e-9, atol=1e-9)
            assert (var is None) == (variance is None)


def test_without_features_the_front_end_is_the_identity():
    """The paper's model: encode returns the inputs themselves and decode the read-out: the model is the
    body."""
    model, z = model_and_inputs({})
    assert not model.reads_features
    x, frame = model.front_end.encode(z)
    assert x is z and frame.scale is None and frame.base is None
    with torch.no_grad():
        assert torch.equal(model(z), model.heads(model.hidden(z))[0])


@pytest.mark.parametrize("options", CONFIGS.values(), ids=CONFIGS.keys())
def test_the_front_end_holds_no_parameters(options):
    """The model's state_dict is the body's (read_in, wpe, blocks, ln_f, read_out: the shipped models' keys)
    and the k-step heads' input network; nothing of the front end."""
    model, _ = model_and_inputs(options)
    body = GPTBody(model.cfg, model.front_end.input_dim)
    heads = [] if model.future_head is None else [f"future_head.{k}" for k in model.future_head.state_dict()]
    assert list(model.state_dict()) == list(body.state_dict()) + heads
    assert not isinstance(model.front_end, torch.nn.Module)
