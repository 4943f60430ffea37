"""mop.predictors: make_predictor and the registry metadata refuse what they do not know (a misspelt option
or key is a one-line MopError listing the accepted ones, never silently dropped)."""

import pytest
import torch

from mop.errors import MopError
from mop.filters.particle import ParticleFilterPredictor
from mop.predictors import PREDICTOR_KEYS, PREDICTORS, accepted_options, make_predictor
from mop.registry import Registry
from tests.reference import linear_traj


def test_an_unknown_option_is_refused_in_one_line_naming_the_accepted_ones():
    with pytest.raises(MopError) as err:
        make_predictor("pf", num_particle=10, sed=3)
    text = str(err.value)
    assert len(text.splitlines()) == 1
    assert "'num_particle', 'sed'" in text and "num_particles, seed, project" in text
    with pytest.raises(MopError, match="'kalman' takes no option 'seed'; it accepts: no options"):
        make_predictor("kalman", seed=0)


def test_the_options_given_are_the_options_used():
    """make_predictor('pf', num_particles=N, seed=s) predicts exactly what the constructor with N and s does
    (and not the defaults 1000 and 0)."""
    traj = linear_traj(num_systems=2, horizon=6)
    made = make_predictor("pf", num_particles=37, seed=5).predict(traj)
    torch.testing.assert_close(made, ParticleFilterPredictor(37, seed=5).predict(traj), rtol=0, atol=0)
    assert not torch.equal(made, ParticleFilterPredictor().predict(traj))


def test_shared_options_go_to_the_predictors_that_take_them():
    """shared= is how a caller offers one seed to many predictors: taken where accepted, else left out;
    an option given by name overrides the shared one."""
    traj = linear_traj(num_systems=2, horizon=6)
    pf = make_predictor("pf", shared={"seed": 4, "run_dir": "x"}, num_particles=30)
    torch.testing.assert_close(pf.predict(traj), ParticleFilterPredictor(30, seed=4).predict(traj))
    pf = make_predictor("pf", shared={"seed": 4}, seed=6, num_particles=30)
    torch.testing.assert_close(pf.predict(traj), ParticleFilterPredictor(30, seed=6).predict(traj))
    kf = make_predictor("kalman", shared={"seed": 4})
    assert kf.name == "kalman" and accepted_options("kalman") == []


def test_every_registered_predictor_declares_only_known_metadata():
    for name in PREDICTORS.names():
        assert set(PREDICTORS.meta(name)) <= set(PREDICTOR_KEYS), name


def test_a_misspelt_metadata_key_is_refused_where_registered_and_where_read():
    with pytest.raises(MopError, match="has no metadata key 'needs_sytem'; accepted keys: needs_system"):
        PREDICTORS.add("typo", object, needs_sytem=True)
    assert "typo" not in PREDICTORS
    with pytest.raises(MopError, match="predictor 'kalman' has no metadata key 'lerned'"):
        PREDICTORS.meta("kalman").get("lerned")
    with pytest.raises(MopError, match="has no metadata key 'lerned'"):
        PREDICTORS.meta("kalman")["lerned"]
    with pytest.raises(MopError, match="has no metadata key 'default_refrence'"):
        PREDICTORS.default("default_refrence")
    assert PREDICTORS.meta("kalman").get("learned") is None  # a declared key not set reads as unset


def test_a_registry_without_declared_keys_takes_any():
    reg = Registry("thing")
    reg.add("a", object(), anything=1)
    assert reg.meta("a").get("anything") == 1 and reg.meta("a").get("other") is None
