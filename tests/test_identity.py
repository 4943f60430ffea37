"""mop.identity: a knob added with a default, in any section, changes no run's identity (config.json, the
run hash that names run directories, the look-up of a shipped pretrained model). Each test adds the field
in a dataclass made here, as a later version of mop would add it to a family's or section's config."""

import dataclasses
import json

import pytest

import mop.pretrained as pretrained
from mop.config import DataConfig, ModelConfig, RunConfig, TrainConfig, from_dict, to_dict
from mop.experiments import get_experiment, run_config
from mop.experiments.planning import config_hash
from mop.experiments.pretrained_build import training_config
from mop.pretrained import find_shipped
from mop.pretrained.catalog import catalog_entry
from mop.runs import load_config
from mop.systems import FAMILIES
from mop.train.rundir import check_run_dir


def with_new_field(config, name: str, default):
    """`config` as an instance of a subclass of its class with one more field `name` (at its default)."""
    cls = dataclasses.make_dataclass(
        type(config).__name__, [(name, type(default), default)], bases=(type(config),), frozen=True
    )
    return cls(**{f.name: getattr(config, f.name) for f in dataclasses.fields(config)})


def extended(config: RunConfig, section: str, name: str = "input_gain", default=0.0) -> RunConfig:
    return dataclasses.replace(config, **{section: with_new_field(getattr(config, section), name, default)})


@pytest.mark.parametrize("section", ["system", "model", "train", "data"])
def test_a_new_field_at_its_default_changes_no_hash(section):
    data = DataConfig(path="recordings.npz") if section == "data" else None
    base = dataclasses.replace(run_config(get_experiment("linear"), "small"), data=data)
    new = extended(base, section)
    assert to_dict(new) == to_dict(base) and config_hash(new) == config_hash(base)
    set_gain = dataclasses.replace(getattr(new, section), input_gain=0.5)
    changed = dataclasses.replace(new, **{section: set_gain})
    assert to_dict(changed)[section]["input_gain"] == 0.5 and config_hash(changed) != config_hash(base)
    assert "input_gain" in to_dict(new, omit_defaults=False)[section]  # every key, where asked for


def test_the_hash_of_a_default_config_is_the_one_from_before():
    assert config_hash(RunConfig()) == "3cb1a1576f0f"
    assert config_hash(extended(RunConfig(), "system")) == "3cb1a1576f0f"


@pytest.mark.parametrize("name", pretrained.shipped_names())
def test_shipped_models_keep_their_identity_and_are_found_with_a_new_field(name):
    """config.json of every shipped model is what to_dict writes for its config today; with a field added
    to its family's config (LinearConfig.input_gain, the measured break of `reproduce --pretrained`) the
    look-up still finds it, and its directory is still recognised as holding that config."""
    saved = json.loads((pretrained.ROOT / name / "config.json").read_text())
    config = load_config(f"pretrained:{name}")
    assert json.loads(json.dumps(to_dict(config))) == saved
    new = extended(extended(extended(config, "system", "added_knob", 1), "model", "added", ""), "train")
    assert json.loads(json.dumps(to_dict(new))) == saved
    assert find_shipped(to_dict(new)) is not None
    check_run_dir(pretrained.ROOT / name, new)  # MopError if it saw another config


@pytest.mark.parametrize("name", pretrained.shipped_names())
def test_reproduce_pretrained_finds_the_model_its_experiment_built(name):
    """`mop reproduce EXPERIMENT --pretrained` evaluates the model the catalog says EXPERIMENT built, also
    where another shipped model shares its class (duffing and its records start)."""
    entry = catalog_entry(name)
    config = training_config(entry)
    assert find_shipped(to_dict(config), experiment=entry.experiment) == f"pretrained:{name}"


def test_reproduce_linear_pretrained_finds_the_shipped_model_with_a_new_system_field():
    config = run_config(get_experiment("linear"), "small")
    assert find_shipped(to_dict(config)) == "pretrained:linear"
    assert find_shipped(to_dict(extended(config, "system"))) == "pretrained:linear"


def test_a_config_json_without_the_new_key_reads_back_at_its_default():
    base = RunConfig()
    new = extended(base, "model", "added", 7)
    assert from_dict(type(new.model), to_dict(base)["model"]) == new.model


@pytest.mark.parametrize("family", FAMILIES.names())
def test_every_family_writes_its_knobs_and_reads_back_equal(family):
    config = from_dict(RunConfig, {"system": {"family": family}})
    assert from_dict(RunConfig, json.loads(json.dumps(to_dict(config)))) == config
    assert to_dict(config)["system"]["family"] == family


def test_a_new_family_writes_only_the_knobs_away_from_their_defaults():
    """A family registered after this rule (its config made here) writes its family and changed knobs."""
    base = from_dict(RunConfig, {"system": {"family": "linear"}})
    new = extended(base, "system", "coupling", 0.0)
    object.__setattr__(new.system, "family", "later-family")
    assert to_dict(new)["system"] == {"family": "later-family"}
    object.__setattr__(new.system, "coupling", 0.3)
    assert to_dict(new)["system"] == {"family": "later-family", "coupling": 0.3}


def test_model_and_train_sections_keep_the_keys_written_before():
    """The keys added after the first runs (model.rls_order ..., train.missing_rate ...) are left out at
    their defaults, as before; all others are written."""
    config = RunConfig()
    written = to_dict(config)
    assert "rls_order" not in written["model"] and "missing_rate" not in written["train"]
    assert set(written["model"]) < {f.name for f in dataclasses.fields(ModelConfig)}
    assert "num_layers" in written["model"] and "steps" in written["train"]
    assert set(written["train"]) < {f.name for f in dataclasses.fields(TrainConfig)}
