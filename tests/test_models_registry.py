"""The model registry: every registered model round-trips through safetensors; names unique and checked;
loading a run imports neither the trainer nor TensorBoard."""

import subprocess
import sys

import pytest
import torch
from torch import nn

from mop.checkpoint import load_model_weights, save_model
from mop.config import ModelConfig
from mop.errors import MopError
from mop.models import build_model, model_names, register_model, registry


def tiny(arch: str, **kw) -> ModelConfig:
    base = dict(arch=arch, num_layers=2, num_heads=2, width=16, context=12, input_dim=3, output_dim=2)
    return ModelConfig(**{**base, **kw})


def test_builtin_models_registered():
    assert {"gpt", "gru"} <= set(model_names())


@pytest.mark.parametrize("readout", ["mean", "gaussian"])
@pytest.mark.parametrize("arch", model_names())
def test_save_load_round_trip(tmp_path, arch, readout):
    torch.manual_seed(0)
    model = build_model(tiny(arch, readout=readout)).eval()
    save_model(tmp_path / "model.safetensors", model)
    torch.manual_seed(1)
    fresh = build_model(tiny(arch, readout=readout)).eval()
    load_model_weights(tmp_path / "model.safetensors", fresh)
    z = torch.randn(3, 12, 3, generator=torch.Generator().manual_seed(2))
    with torch.no_grad():
        assert torch.equal(model(z), fresh(z))
        if readout == "gaussian":
            for a, b in zip(model.predict_distribution(z), fresh.predict_distribution(z), strict=True):
                assert torch.equal(a, b)


def test_unknown_arch_names_the_known_ones():
    with pytest.raises(MopError, match="model.arch must be one of 'gpt', 'gru'.*got 'lstm'"):
        build_model(tiny("lstm"))


def test_duplicate_name_refused():
    with pytest.raises(MopError, match="'gpt' is already registered"):
        register_model("gpt")(nn.Linear)


def test_new_model_registers_itself(monkeypatch):
    monkeypatch.setattr(registry, "_MODELS", dict(registry._MODELS))

    @register_model("toy")
    class Toy(nn.Module):
        def __init__(self, cfg: ModelConfig) -> None:
            super().__init__()
            self.cfg = cfg

    assert "toy" in model_names() and isinstance(build_model(tiny("toy")), Toy)


def test_loading_does_not_import_the_trainer():
    code = (
        "import sys, mop.runs; "
        "bad = [m for m in sys.modules if m.startswith(('mop.train', 'torch.utils.tensorboard'))]; "
        "assert not bad, bad"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
