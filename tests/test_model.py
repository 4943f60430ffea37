"""The transformer: shapes, causality, overfitting, KV-cache streaming, Gaussian NLL, config errors."""

import math

import pytest
import torch

from mop.config import ModelConfig
from mop.errors import MopError
from mop.models import build_model


def tiny(**kw) -> ModelConfig:
    base = dict(num_layers=2, num_heads=2, width=16, context=12, input_dim=3, output_dim=2)
    return ModelConfig(**{**base, **kw})


def inputs(B=4, T=12, d=3, seed=0):
    return torch.randn(B, T, d, generator=torch.Generator().manual_seed(seed))


@pytest.mark.parametrize("readout", ["mean", "gaussian"])
@pytest.mark.parametrize("position", ["learned", "rope"])
def test_shapes(readout, position):
    model = build_model(tiny(readout=readout, position=position))
    z = inputs()
    assert model(z).shape == (4, 12, 2)
    assert model.loss(z, torch.zeros(4, 12, 2)).shape == ()
    if readout == "gaussian":
        mu, var = model.predict_distribution(z)
        assert mu.shape == var.shape == (4, 12, 2) and bool((var > 0).all())
    else:
        with pytest.raises(MopError):
            model.predict_distribution(z)


@pytest.mark.parametrize("arch", ["gpt", "gru", "deep-lru"])
@pytest.mark.parametrize("readout", ["mean", "gaussian"])
def test_causality(arch, readout):
    """Changing input t0 leaves outputs before t0 unchanged and changes the output at t0."""
    model = build_model(tiny(arch=arch, readout=readout)).eval()
    z = inputs()
    t0 = 7
    z2 = z.clone()
    z2[:, t0:] += torch.randn(4, 12 - t0, 3)
    out, out2 = model(z), model(z2)
    assert torch.equal(out[:, :t0], out2[:, :t0])
    assert (out[:, t0] - out2[:, t0]).abs().max() > 1e-4
    if readout == "gaussian":
        (_, v), (_, v2) = model.predict_distribution(z), model.predict_distribution(z2)
        assert torch.equal(v[:, :t0], v2[:, :t0])


@pytest.mark.parametrize("position", ["learned", "rope"])
@pytest.mark.parametrize("readout", ["mean", "gaussian"])
def test_stream_equals_forward_inside_context(position, readout):
    model = build_model(tiny(position=position, readout=readout)).eval()
    z = inputs()
    with torch.no_grad():
        mu, var = model.predict_distribution(z) if readout == "gaussian" else (model(z), None)
        cache = model.init_cache(4)
        steps = [model.step_distribution(z[:, t], cache) for t in range(12)]
    assert torch.allclose(torch.stack([s[0] for s in steps], 1), mu, atol=1e-5, rtol=0)
    if var is not None:
        assert torch.allclose(torch.stack([s[1] for s in steps], 1), var, atol=1e-5, rtol=0)


def test_rope_stream_beyond_context_is_shift_invariant():
    """With rotary positions and one layer, the rolling cache sees exactly the last C inputs, relative
    positions only, so step t equals a plain forward on the window z_{t-C+1}..z_t."""
    C = 6
    model = build_model(tiny(position="rope", num_layers=1, context=C)).eval()
    z = inputs(T=20)
    with torch.no_grad():
        cache = model.init_cache(4)
        streamed = torch.stack([model.step(z[:, t], cache) for t in range(20)], 1)  # (B, T, m)
        for t in range(C, 20):
            window = model(z[:, t - C + 1 : t + 1])[:, -1]
            assert torch.allclose(streamed[:, t], window, atol=1e-5, rtol=0)


def test_gaussian_nll_matches_torch_normal():
    model = build_model(tiny(readout="gaussian"))
    z, y = inputs(), inputs(d=2, seed=1)
    mu, var = model.predict_distribution(z)
    expected = -torch.distributions.Normal(mu, var.sqrt()).log_prob(y).mean()
    assert torch.allclose(model.loss(z, y), expected, atol=1e-5)


def test_mean_loss_is_mse():
    model = build_model(tiny())
    z, y = inputs(), inputs(d=2, seed=1)
    assert torch.allclose(model.loss(z, y), ((model(z) - y) ** 2).mean())


@pytest.mark.parametrize("arch", ["gpt", "gru", "deep-lru"])
def test_overfits_one_batch(arch):
    """A tiny model memorises one fixed batch: loss falls by a factor > 20 in 300 Adam steps."""
    torch.manual_seed(0)
    model = build_model(tiny(arch=arch, width=32))
    z, y = inputs(B=8), inputs(B=8, d=2, seed=1)
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    first = model.loss(z, y).item()
    for _ in range(300):
        opt.zero_grad()
        loss = model.loss(z, y)
        loss.backward()
        opt.step()
    assert loss.item() < first / 20


def test_gpt2_init_scales():
    model = build_model(tiny(num_layers=4, width=64, num_heads=4))
    std = model.blocks[0].mlp.proj.weight.std().item()
    assert abs(std - 0.02 / math.sqrt(8)) < 0.002
    assert abs(model.blocks[0].attn.qkv.weight.std().item() - 0.02) < 0.002


def test_config_errors():
    with pytest.raises(MopError, match="num_heads"):
        ModelConfig(num_heads=3, width=16)
    with pytest.raises(MopError, match="position"):
        ModelConfig(position="sinusoid")
    with pytest.raises(MopError, match="input_dim"):
        build_model(ModelConfig(num_layers=1, width=16, num_heads=2))
    with pytest.raises(MopError, match="context"):
        build_model(tiny())(inputs(T=13))
