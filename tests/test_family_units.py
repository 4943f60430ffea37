"""A family written in other units (model.output_units / input_units, mop.train.auto.family_units): auto
reads it in the family's units, so the thermal network 30x larger and 30x smaller get the same keys; a model
trained in units predicts in the data's units, scaled exactly with the data; units of 1 change nothing."""

import dataclasses
from pathlib import Path

import pytest
import torch

from mop.config import ModelConfig, RunConfig, SystemConfig, TrainConfig
from mop.errors import MopError
from mop.experiments.presets import get_preset
from mop.models.predictor import LearnedPredictor
from mop.plugins import import_plugin
from mop.systems import generator, make_family
from mop.train import auto, train_model

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def thermal(scale: float) -> SystemConfig:
    """The thermal network with every signal `scale` times its size (heater, disturbances, sensor noise and
    initial state; the redraw bound alike): the same systems in other units, y and u exactly scale x."""
    import_plugin(EXAMPLES / "thermal_network.py")
    return SystemConfig(
        family="thermal-network",
        heater_std=1.0 * scale,
        disturbance_std=0.1 * scale,
        sensor_std=0.1 * scale,
        initial_std=1.0 * scale,
        max_abs=50.0 * scale,
    )


def test_units_are_the_channels_median_rms_only_far_from_unit_scale():
    g = torch.Generator().manual_seed(0)
    y = torch.randn(200, 51, 2, generator=g, dtype=torch.float64) * torch.tensor(
        [30.0, 3.0], dtype=torch.float64
    )
    units = auto.family_units(y)
    rms = y.pow(2).mean(1).sqrt().median(0).values
    assert units == pytest.approx(rms.tolist(), rel=1e-12) and units[0] > 10  # one channel far: all get units
    assert auto.family_units(y / 30) == ()  # 1 and 0.1: near unit scale, read as simulated
    assert auto.family_units(None) == ()


def test_auto_reads_a_family_in_its_units():
    """x30 and x1/30: the same orders, prior and steps, units 900 apart; at its own scale, no units."""
    small = get_preset("small")
    resolve = lambda s: auto.resolve_features(RunConfig(system=s, model=small.model, train=small.train))  # noqa: E731
    big, tiny, own = resolve(thermal(30.0)), resolve(thermal(1 / 30)), resolve(thermal(1.0))
    assert own.model.output_units is None and own.model.input_units is None
    for name in ("output_units", "input_units"):
        ratio = torch.tensor(getattr(big.model, name), dtype=torch.float64) / torch.tensor(
            getattr(tiny.model, name), dtype=torch.float64
        )
        torch.testing.assert_close(ratio, torch.full_like(ratio, 900.0), rtol=1e-9, atol=0)
    keys = ("rls_order", "arx_order", "input_scale", "features")
    assert [getattr(big.model, k) for k in keys] == [getattr(tiny.model, k) for k in keys]
    assert big.train.steps == tiny.train.steps
    for name in ("rls_prior", "rls_prior_cov", "rls_prior_weights"):
        a, b = torch.tensor(getattr(big.model, name)), torch.tensor(getattr(tiny.model, name))
        torch.testing.assert_close(a, b, rtol=1e-6, atol=1e-9)


def _trained(system: SystemConfig, units: float | None, tmp: Path):
    m = ModelConfig(num_layers=1, num_heads=2, width=16, context=20, output_dim=2, input_dim=3)
    if units is not None:
        m = dataclasses.replace(m, output_units=[units, 2 * units], input_units=[3 * units])
    cfg = RunConfig(system=system, model=m, train=TrainConfig(steps=6, batch_size=8, horizon=20, log_every=3))
    return train_model(cfg, tmp, progress=False)


def test_a_model_in_units_predicts_in_the_datas_units(tmp_path):
    """Trained on x30 in units u and on x1/30 in units u / 900: the same model in its own units, so its
    predictions on the same test systems, each in its units, are 900 apart; units of 1 are no units."""
    big, tiny = (
        _trained(thermal(30.0), 30.0, tmp_path / "big"),
        _trained(thermal(1 / 30), 1 / 30, tmp_path / "tiny"),
    )
    test = lambda s: make_family(s, torch.float64).generate(16, 20, generator=generator(5))  # noqa: E731
    yhat_big = LearnedPredictor(big).predict(test(thermal(30.0)))
    yhat_tiny = LearnedPredictor(tiny).predict(test(thermal(1 / 30)))
    torch.testing.assert_close(yhat_big.double(), 900 * yhat_tiny.double(), rtol=1e-3, atol=1e-4)
    streamed = LearnedPredictor(big, mode="stream").predict(test(thermal(30.0)))  # the KV cache, in units too
    torch.testing.assert_close(streamed, yhat_big, rtol=1e-4, atol=1e-4)
    plain = _trained(thermal(1.0), None, tmp_path / "plain")
    ones = RunConfig(
        system=thermal(1.0),
        model=dataclasses.replace(plain.cfg, output_units=[1.0, 1.0], input_units=[1.0]),
        train=TrainConfig(steps=6, batch_size=8, horizon=20, log_every=3),
    )
    unit = train_model(ones, tmp_path / "ones", progress=False)
    traj = test(thermal(1.0))
    assert torch.equal(LearnedPredictor(plain).predict(traj), LearnedPredictor(unit).predict(traj))


def test_bad_units_are_one_line():
    with pytest.raises(MopError, match="model.output_units must be a list of positive numbers"):
        ModelConfig(output_units=[1.0, -2.0])


def test_units_of_another_channel_count_are_one_line():
    from mop.models import build_model

    with pytest.raises(MopError, match=r"model.input_units needs one number per channel \(1\), got 2"):
        build_model(ModelConfig(output_dim=2, input_dim=3, input_units=[1.0, 2.0]))
