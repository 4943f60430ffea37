"""The sliding free run (mop.models.slide) against the window path it replaces: one forward of the last C
inputs per simulated step (mop.models.simulate.windowed_rollout), on float64 models."""

import pytest
import torch

from mop.config import ModelConfig
from mop.models import build_model
from mop.models import simulate as sim
from mop.models.normalization import Normalization
from mop.models.predictor import LearnedPredictor
from mop.systems import Trajectories

CONTEXT = 8


def random_predictor(
    position: str, layers: int, inputs: int, features: dict, normalised: bool, seed: int = 0
):
    """A float64 transformer with N(0, 0.2^2) weights (every attention weight matters), its read-out small
    so that a 40-step free run stays finite."""
    torch.manual_seed(seed)
    cfg = ModelConfig(
        arch="gpt",
        num_layers=layers,
        num_heads=2,
        width=16,
        context=CONTEXT,
        position=position,
        input_dim=2 + inputs,
        output_dim=2,
        **features,
    )
    model = build_model(cfg).double()
    with torch.no_grad():
        for p in model.parameters():
            p.normal_(0.0, 0.2)
        model.read_out.weight.mul_(0.1)
    norm = None
    if normalised:
        norm = Normalization.from_lists([0.5, -1.0], [2.0, 0.5], [0.1] * inputs, [3.0] * inputs)
    return LearnedPredictor(model, normalization=norm)


def record(horizon: int, inputs: int, seed: int = 1) -> Trajectories:
    """Two records of a stable linear plant driven by Gaussian inputs (outputs (2, T+1, 2))."""
    g = torch.Generator().manual_seed(seed)
    u = torch.randn(2, horizon + 1, max(inputs, 1), generator=g, dtype=torch.float64)
    y = torch.zeros(2, horizon + 1, 2, dtype=torch.float64)
    for t in range(1, horizon + 1):
        y[:, t, 0] = 0.8 * y[:, t - 1, 0] + 0.3 * y[:, t - 1, 1] + u[:, t - 1, 0]
        y[:, t, 1] = -0.2 * y[:, t - 1, 0] + 0.7 * y[:, t - 1, 1] + 0.5 * u[:, t - 1, -1]
    y = y + 0.05 * torch.randn(y.shape, generator=g, dtype=torch.float64)
    return Trajectories(y, u[..., :inputs] if inputs else None)


def window_path(p, traj: Trajectories, context: int, monkeypatch) -> torch.Tensor:
    with monkeypatch.context() as m:
        m.setattr(sim, "slide_fast", lambda model: False)
        return sim.simulate(p, traj, context)


ARX = {"rls_order": 2, "arx_order": 3, "rls_offset": True}
CASES = [
    ("learned", 1, 1, ARX, True),  # the records recipe's shape: ARX feature with an intercept, normalised
    ("rope", 2, 2, ARX, False),
    ("learned", 2, 0, {"rls_order": 3}, True),  # RLS-AR feature, no inputs
    ("rope", 1, 1, {}, False),  # no feature
    ("learned", 1, 1, {**ARX, "rls_prior": [0.1] * 2 * (2 * 2 + 3 * 1 + 1)}, False),  # listed prior
    # a fixed feature (model.rls_fixed): no window updates its fit
    ("learned", 1, 1, {**ARX, "rls_prior": [0.1] * 2 * (2 * 2 + 3 * 1 + 1), "rls_fixed": True}, True),
]


@pytest.mark.parametrize(("position", "layers", "inputs", "features", "normalised"), CASES)
@pytest.mark.parametrize("context", [1, 5, CONTEXT, 20])
def test_sliding_free_run_equals_the_window_path(
    position, layers, inputs, features, normalised, context, monkeypatch
):
    p = random_predictor(position, layers, inputs, features, normalised)
    assert sim.slide_fast(p.model) and sim.simulation_path(p, 40, context) == "window"
    traj = record(40, inputs)
    fast = sim.simulate(p, traj, context)
    slow = window_path(p, traj, context, monkeypatch)
    assert fast.shape == slow.shape == (2, 41 - context, 2)
    assert torch.isfinite(slow).all() and slow.abs().max() > 0.1
    # split_readout rounds the network's read-out to float32, so the paths agree to float32 rounding
    torch.testing.assert_close(fast, slow, rtol=1e-5, atol=1e-5)


def test_models_it_does_not_serve_take_the_window_path():
    p = random_predictor("learned", 1, 1, {**ARX, "record_norm": "causal"}, False)
    assert not sim.slide_fast(p.model)


@pytest.mark.parametrize("context", [1, 5, CONTEXT, 20])
def test_the_cubic_feature_slides_as_the_window_path(context, monkeypatch):
    """model.rls_cubes: the cubes of the output lags in every window's recursion. A random model reading
    an in-context cubic fit blows up in free run sooner or later (its own outputs cubed), so the paths are
    compared step for step up to there: the same steps finite (at least 10), equal where they are."""
    p = random_predictor("learned", 1, 1, {**ARX, "rls_cubes": 2}, False)
    traj = record(40, 1)
    traj = Trajectories(0.1 * traj.y, 0.1 * traj.u)
    fast = sim.simulate(p, traj, context)
    slow = window_path(p, traj, context, monkeypatch)
    finite = torch.isfinite(slow) & (slow.abs() < 1e6)
    assert finite[:, :10].all()
    steps = int(finite.all(-1).all(0).long().cumprod(0).sum())  # the leading steps finite in every record
    torch.testing.assert_close(fast[:, :steps], slow[:, :steps], rtol=1e-5, atol=1e-6)
