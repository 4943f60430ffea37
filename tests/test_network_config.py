"""The network section per architecture (mop.network_config): found by model.arch's name, checking the
network's keys with ModelConfig's messages, while ModelConfig's flat keys and saved configs stay as they
were."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from mop.config import ModelConfig, from_dict
from mop.errors import MopError
from mop.feature_config import FEATURE_CONFIG_KEYS
from mop.network_config import (
    NETWORK_KEYS,
    GenericNetworkConfig,
    GptConfig,
    GruConfig,
    network_config_class,
    network_config_names,
)

PRETRAINED = sorted((Path(__file__).resolve().parents[1] / "mop" / "pretrained").glob("*/config.json"))

# ModelConfig's fields, in the order config.json saves them (hard-coded: a change here is a format change)
MODEL_KEYS = (
    "arch num_layers num_heads width context input_dim output_dim readout dropout position "
    "input_scale record_norm residual_scale record_moments record_prior_steps residual_decay rls_order "
    "arx_order rls_offset rls_cubes rls_prior rls_prior_cov rls_prior_weights rls_prior_noise rls_fixed "
    "rls_fill_range "
    "rls_p0 output_units input_units features observation_mask forecast_mode horizons horizon_loss gap_loss"
).split()
READOUT_KEYS = ("forecast_mode", "horizons", "horizon_loss", "gap_loss")


def test_saved_key_order_and_defaults_are_unchanged():
    assert [f.name for f in dataclasses.fields(ModelConfig)] == MODEL_KEYS
    defaults = {key: getattr(ModelConfig(), key) for key in NETWORK_KEYS}
    assert defaults == {
        "num_layers": 12,
        "num_heads": 8,
        "width": 256,
        "context": 50,
        "input_dim": 0,
        "output_dim": 0,
        "readout": "mean",
        "dropout": 0.0,
        "position": "learned",
    }
    assert ModelConfig().arch == "gpt"
    assert ("arch", *NETWORK_KEYS, *FEATURE_CONFIG_KEYS, *READOUT_KEYS) == tuple(MODEL_KEYS)


@pytest.mark.parametrize("path", PRETRAINED, ids=lambda p: p.parent.name)
def test_shipped_model_sections_split_without_loss(path):
    """arch, the network section, the front end and the read-out rebuild the saved model section."""
    saved = json.loads(path.read_text())["model"]
    cfg = from_dict(ModelConfig, saved)
    network = dataclasses.asdict(cfg.network)
    assert type(cfg.network) is network_config_class(cfg.arch)
    front_end = dataclasses.asdict(cfg.front_end)
    readout = {key: getattr(cfg, key) for key in READOUT_KEYS}
    unread = {key: getattr(cfg, key) for key in NETWORK_KEYS if key not in network}  # keys arch reads not
    assert not set(network) & set(front_end)
    rebuilt = ModelConfig(arch=cfg.arch, **network, **unread, **front_end, **readout)
    assert rebuilt == cfg
    assert {k: v for k, v in dataclasses.asdict(rebuilt).items() if k in saved} == saved


def test_sections_are_found_by_name():
    assert {"gpt", "gru"} <= set(network_config_names())
    assert network_config_class("gpt") is GptConfig
    assert network_config_class("gru") is GruConfig
    assert network_config_class("a-plugin") is GenericNetworkConfig
    assert type(ModelConfig().network) is GptConfig
    assert type(ModelConfig(arch="gru").network) is GruConfig
    assert type(ModelConfig(arch="a-plugin").network) is GenericNetworkConfig
    assert GptConfig.keys() == NETWORK_KEYS
    assert GruConfig.keys() == tuple(k for k in NETWORK_KEYS if k not in ("num_heads", "position"))


BAD = [
    ("gpt", {"num_heads": 3}, "model.num_heads (3) must divide model.width (256)"),
    ("gpt", {"num_layers": 0}, "model.num_layers"),
    ("gpt", {"position": "sinusoid"}, "model.position"),
    ("gpt", {"dropout": 1.0}, "model.dropout must be in [0, 1), got 1.0"),
    ("gru", {"width": 0}, "model.width"),
    ("gru", {"readout": "laplace"}, "model.readout"),
    ("gru", {"output_dim": -1}, "model.input_dim/output_dim must be >= 0"),
    ("a-plugin", {"num_heads": 5}, "model.num_heads (5) must divide model.width (256)"),
]


@pytest.mark.parametrize(("arch", "bad", "words"), BAD)
def test_bad_network_values_same_message_through_model_and_section(arch, bad, words):
    with pytest.raises(MopError) as through_model:
        ModelConfig(arch=arch, **bad)
    values = {**dataclasses.asdict(ModelConfig(arch=arch)), **bad}
    section = network_config_class(arch)
    with pytest.raises(MopError) as through_section:
        section(**{key: values[key] for key in section.keys()})
    assert str(through_model.value) == str(through_section.value)
    assert words in str(through_model.value) and "\n" not in str(through_model.value)


def test_gru_reads_no_heads_or_position():
    """Keys the GRU does not read are left to the architectures that do."""
    assert ModelConfig(arch="gru", num_heads=3).network == ModelConfig(arch="gru").network
    with pytest.raises(MopError, match="must divide"):
        ModelConfig(arch="gpt", num_heads=3)
