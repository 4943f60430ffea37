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
from mop.models.forecast import forecast_path
from mop.models.interface import CAPABILITIES, LearnedModel, check_model_class
from mop.models.predictor import LearnedPredictor
from mop.models.simulate import simulation_path
from mop.systems.base import Trajectories
from tests.reference_models import reference_forecast, reference_simulate


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
    with pytest.raises(MopError, match="model.arch must be one of 'deep-lru', 'gpt', 'gru'.*got 'lstm'"):
        build_model(tiny("lstm"))


def test_duplicate_name_refused():
    with pytest.raises(MopError, match="'gpt' is already registered"):
        register_model("gpt")(nn.Linear)


class Toy(LearnedModel):
    """The least a registered architecture declares: every flag, forward, predict_distribution and loss."""

    context_limited = supports_stream = supports_branch = branchable_state = False
    has_direct_heads = supports_features = reads_features = False

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__(cfg)
        self.read_out = nn.Linear(cfg.input_dim, cfg.output_dim)

    def forward(self, inputs):
        return self.read_out(inputs)

    def predict_distribution(self, inputs):
        return self(inputs), torch.ones_like(self(inputs))

    def loss(self, inputs, targets):
        return ((self(inputs) - targets) ** 2).mean()


def test_new_model_registers_itself(monkeypatch):
    monkeypatch.setattr(registry, "_MODELS", dict(registry._MODELS))
    register_model("toy")(Toy)
    assert "toy" in model_names() and isinstance(build_model(tiny("toy")), Toy)


def test_an_undeclared_member_is_refused_in_one_line(monkeypatch):
    """A class that leaves a capability flag or a required method undeclared, or declares a flag True
    without its methods, is refused at registration, naming what is missing."""
    monkeypatch.setattr(registry, "_MODELS", dict(registry._MODELS))
    no_flag = type("NoFlag", (Toy,), {"reads_features": LearnedModel.reads_features})
    no_loss = type("NoLoss", (Toy,), {"loss": LearnedModel.loss})
    false_promise = type("FalsePromise", (Toy,), {"supports_stream": True})
    per_model = type("PerModel", (Toy,), {"supports_features": property(lambda self: True)})
    cases = [
        (no_flag, "model class NoFlag \\(arch 'a'\\) does not declare reads_features"),
        (no_loss, "does not declare loss"),
        (false_promise, "declares supports_stream = True but does not define init_cache, step_distribution"),
        (nn.Linear, "must derive from mop.models.interface.LearnedModel"),
        (per_model, "must set supports_features to True or False in its class body"),
    ]
    for cls, message in cases:
        with pytest.raises(MopError, match=message) as err:
            register_model("a")(cls)
        assert "\n" not in str(err.value)
    assert "a" not in model_names()


def test_a_path_the_model_does_not_declare_raises(monkeypatch):
    model = Toy(tiny("gpt"))
    with pytest.raises(MopError, match="does not declare supports_stream"):
        model.init_cache(2)


def test_a_model_that_declares_no_capability_takes_the_plain_paths():
    """A new architecture with every optional flag False predicts by its forward, forecasts and simulates one
    forward per step (forecast_path / simulation_path: "window"), equal to the definition, and refuses the
    stream mode in one line."""
    torch.manual_seed(0)
    model = Toy(tiny("gpt", output_dim=2, input_dim=3)).double()
    p = LearnedPredictor(model)
    g = torch.Generator().manual_seed(1)
    y, u = torch.randn(2, 9, 2, generator=g), torch.randn(2, 9, 1, generator=g)
    traj = Trajectories(y.double(), u.double())
    assert forecast_path(p, traj.horizon) == "window" and simulation_path(p, traj.horizon, 3) == "window"
    torch.testing.assert_close(p.forecast(traj, 3), reference_forecast(p, traj, 3), equal_nan=True)
    torch.testing.assert_close(p.simulate(traj, 3), reference_simulate(p, traj, 3))
    with pytest.raises(MopError, match="does not stream; use mode 'window'"):
        LearnedPredictor(model, mode="stream")


@pytest.mark.parametrize("arch", model_names())
def test_builtin_models_declare_their_capabilities(arch):
    """The built-in classes pass the registration check and answer every declared flag as a bool."""
    model = build_model(tiny(arch))
    check_model_class(arch, type(model))
    assert all(isinstance(getattr(model, flag), bool) for flag in CAPABILITIES)
    assert registry.reads_features(arch) is type(model).supports_features is (arch == "gpt")


def test_loading_does_not_import_the_trainer():
    code = (
        "import sys, mop.runs; "
        "bad = [m for m in sys.modules if m.startswith(('mop.train', 'torch.utils.tensorboard'))]; "
        "assert not bad, bad"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
