"""The feature front end as its own section (mop.feature_config.FeatureConfig) while ModelConfig keeps its
keys flat: the fields, their order, defaults and types are the ones every saved config.json was written with;
each shipped model's config.json loads, writes back the same keys and splits into network and front end
without loss; FeatureConfig refuses a bad front end with the message ModelConfig gives; a model.* override
of a front-end key reaches the section."""

import dataclasses
import json
import typing
from pathlib import Path

import pytest

from mop.config import ModelConfig, RunConfig, apply_overrides, from_dict, to_dict
from mop.errors import MopError
from mop.feature_config import FEATURE_CONFIG_KEYS, FeatureConfig

PRETRAINED = sorted((Path(__file__).resolve().parents[1] / "mop" / "pretrained").glob("*/config.json"))

# ModelConfig's keys in the order config.json has always written them
SAVED_ORDER = (
    *("arch", "num_layers", "num_heads", "width", "context", "input_dim", "output_dim", "readout"),
    *("dropout", "position", "input_scale", "record_norm", "residual_scale", "record_moments"),
    *("record_prior_steps", "residual_decay", "rls_order", "arx_order", "rls_offset", "rls_cubes"),
    *("rls_prior", "rls_prior_cov", "rls_prior_weights", "rls_prior_noise", "rls_fixed", "rls_fill_range"),
    "rls_p0",
    "output_units",
    *("input_units", "features", "observation_mask", "forecast_mode", "horizons", "horizon_loss", "gap_loss"),
)
# the front end's defaults a saved config.json leaves out (mop.identity writes a key away from its default)
SAVED_DEFAULTS = {
    **{"input_scale": "none", "record_norm": "none", "residual_scale": "none", "record_moments": "measured"},
    **{"record_prior_steps": 0, "residual_decay": 0.5, "rls_order": 0, "arx_order": 0, "rls_offset": False},
    **{"rls_cubes": 0, "rls_prior": "none", "rls_prior_cov": None, "rls_prior_weights": None},
    **{
        "rls_prior_noise": 0.0,
        "rls_fixed": False,
        "rls_fill_range": None,
        "rls_p0": 1.0,
        "output_units": None,
        "input_units": None,
    },
    **{"features": "given", "observation_mask": False},
}
# (front-end settings, a word of the message both refuse them with)
BAD_FRONT_ENDS = [
    ({"rls_p0": 0.0}, "rls_p0"),
    ({"rls_fill_range": [0.0]}, "rls_fill_range"),
    ({"rls_prior_weights": [1.0]}, "rls_prior_noise"),
    ({"output_units": [-1.0]}, "output_units"),
    ({"residual_decay": 1.0}, "residual_decay"),
    ({"input_scale": "sometimes"}, "input_scale"),
    ({"rls_order": 41}, "rls_order"),
    ({"rls_order": 2, "rls_fixed": True}, "rls_fixed"),
    ({"rls_offset": 1}, "rls_offset"),
    ({"arx_order": 2}, "arx_order"),
    ({"rls_order": 2, "rls_cubes": 3}, "rls_cubes"),
    ({"rls_offset": True}, "rls_offset"),
    ({"rls_order": 2, "residual_scale": "running"}, "residual_scale"),
    ({"record_norm": "causal", "rls_order": 2, "record_moments": "filled"}, "record_moments"),
    ({"record_prior_steps": 100}, "record_prior_steps"),
]


def test_model_config_keeps_the_saved_keys_with_the_front_ends_defaults_and_types():
    assert tuple(f.name for f in dataclasses.fields(ModelConfig)) == SAVED_ORDER
    first = SAVED_ORDER.index("input_scale")
    assert FEATURE_CONFIG_KEYS == SAVED_ORDER[first : SAVED_ORDER.index("forecast_mode")]
    model, front = typing.get_type_hints(ModelConfig), typing.get_type_hints(FeatureConfig)
    defaults = {f.name: f.default for f in dataclasses.fields(ModelConfig)}
    for f in dataclasses.fields(FeatureConfig):
        assert (model[f.name], defaults[f.name]) == (front[f.name], f.default), f.name
    assert (
        dataclasses.asdict(ModelConfig().front_end) == dataclasses.asdict(FeatureConfig()) == SAVED_DEFAULTS
    )


@pytest.mark.parametrize("path", PRETRAINED, ids=lambda p: p.parent.name)
def test_a_shipped_config_loads_writes_back_the_same_keys_and_splits_without_loss(path):
    saved = json.loads(path.read_text())
    config = from_dict(RunConfig, saved)
    assert to_dict(config) == saved
    model = config.model
    network = {k: v for k, v in dataclasses.asdict(model).items() if k not in FEATURE_CONFIG_KEYS}
    assert ModelConfig(**network, **dataclasses.asdict(model.front_end)) == model
    for key, value in saved["model"].items():
        if key in FEATURE_CONFIG_KEYS:
            assert getattr(model.front_end, key) == value


@pytest.mark.parametrize("settings, word", BAD_FRONT_ENDS, ids=[w for _, w in BAD_FRONT_ENDS])
def test_the_front_end_refuses_what_model_config_refuses_in_the_same_words(settings, word):
    with pytest.raises(MopError) as own:
        FeatureConfig(**settings)
    with pytest.raises(MopError) as model:
        ModelConfig(**settings)
    assert str(own.value) == str(model.value) and f"model.{word}" in str(own.value)


def test_a_read_out_knob_stays_model_configs_and_an_override_reaches_the_front_end():
    with pytest.raises(MopError, match="forecast_mode='gap'"):
        ModelConfig(forecast_mode="gap")  # needs the front end's observation mask: ModelConfig's check
    ModelConfig(forecast_mode="gap", observation_mask=True)
    config = apply_overrides(RunConfig(), ["model.rls_order=3", "model.arx_order=2", "model.rls_offset=true"])
    assert config.model.front_end == FeatureConfig(rls_order=3, arx_order=2, rls_offset=True)
    assert to_dict(config)["model"]["rls_order"] == 3  # saved flat, as before


def test_a_front_end_choice_named_none_is_that_choice_on_the_command_line():
    """model.residual_scale=none is the choice "none" (the command line reads `none` as null, which these
    string keys do not take); a key that takes null keeps it (model.rls_prior_cov=none)."""
    feature = ["model.record_norm=causal", "model.rls_order=2", "model.arx_order=2"]
    start = apply_overrides(RunConfig(), [*feature, "model.residual_scale=running"])
    assert start.model.residual_scale == "running"
    config = apply_overrides(
        start, ["model.residual_scale=none", "model.input_scale=None", "model.rls_prior_cov=none"]
    )
    assert config.model.residual_scale == config.model.input_scale == "none"
    assert apply_overrides(config, ["model.record_norm=NONE"]).model.record_norm == "none"
    assert config.model.rls_prior_cov is None
