"""The GRU baseline: same API as the transformer, exact streaming, reference recurrence."""

import torch

from mop.config import ModelConfig
from mop.models import build_model


def tiny(**kw) -> ModelConfig:
    return ModelConfig(
        **{
            **dict(arch="gru", num_layers=2, width=16, num_heads=2, context=10, input_dim=3, output_dim=2),
            **kw,
        }
    )


def test_stream_equals_forward_beyond_context():
    model = build_model(tiny(readout="gaussian")).eval()
    z = torch.randn(3, 25, 3, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        mu, var = model.predict_distribution(z)
        cache = model.init_cache(3)
        steps = [model.step_distribution(z[:, t], cache) for t in range(25)]
    assert torch.allclose(torch.stack([s[0] for s in steps], 1), mu, atol=1e-5)
    assert torch.allclose(torch.stack([s[1] for s in steps], 1), var, atol=1e-5)


def test_matches_manual_gru_cell_recurrence():
    """forward equals an independent loop over torch.nn.GRUCell with the same weights (one layer)."""
    model = build_model(tiny(num_layers=1)).eval()
    cell = torch.nn.GRUCell(16, 16)
    with torch.no_grad():
        for name in ("weight_ih", "weight_hh", "bias_ih", "bias_hh"):
            getattr(cell, name).copy_(getattr(model.gru, name + "_l0"))
        z = torch.randn(2, 7, 3)
        h = torch.zeros(2, 16)
        outs = []
        for t in range(7):
            h = cell(model.read_in(z[:, t]), h)
            outs.append(model.read_out(model.ln_f(h)))
        assert torch.allclose(torch.stack(outs, 1), model(z), atol=1e-5)
