"""Every registered family, predictor and experiment is found from its registry and exercised here, so a
new entry is tested the moment it registers. Names are unique."""

import dataclasses

import pytest
import torch

from mop.config import RunConfig, SystemConfig, apply_overrides, from_dict, to_dict
from mop.errors import MopError
from mop.experiments.planning import config_hash
from mop.predictors import PREDICTORS, is_learned, make_predictor, needs_system
from mop.registry import Registry
from mop.systems import FAMILIES, generator, make_family, state_space_of

FAMILY_NAMES = FAMILIES.names()


def test_duplicate_names_are_refused():
    reg = Registry("thing")
    reg.add("a", object())
    with pytest.raises(MopError, match="thing 'a' is already registered"):
        reg.add("a", object())
    with pytest.raises(MopError, match="unknown thing 'b'; choose one of a"):
        reg.get("b")


def test_the_default_entry_is_the_one_registered_as_default():
    reg = Registry("thing")
    reg.add("a", object())
    with pytest.raises(MopError, match="one thing must be registered with default=True; none is"):
        reg.default()
    reg.add("b", object(), default=True, panel=True)
    reg.add("c", object(), panel=True)
    assert reg.default() == "b" and reg.flagged("panel") == ["b", "c"] and reg.flagged("nothing") == []
    reg.add("d", object(), default=True)
    with pytest.raises(MopError, match="'b', 'd' are"):
        reg.default()


def test_a_config_without_a_family_is_the_default_familys():
    """SystemConfig() and a RunConfig's system are the paper's linear systems (the family registered as
    default); a default RunConfig keeps its hash, so run directories trained before are reused."""
    assert FAMILIES.default() == "linear" and type(SystemConfig()) is FAMILIES.get("linear").Config
    assert from_dict(SystemConfig, {"max_abs": 3.0}) == SystemConfig(family="linear", max_abs=3.0)
    assert to_dict(RunConfig().system) == to_dict(SystemConfig(family="linear"))
    assert config_hash(RunConfig()) == "3cb1a1576f0f"  # the hash of a default RunConfig before the change
    with pytest.raises(MopError, match="unknown system family ''"):
        SystemConfig(family="")


@pytest.mark.parametrize("name", FAMILY_NAMES)
def test_every_family_is_seeded_bounded_and_round_trips_its_config(name):
    config = SystemConfig(family=name)
    assert type(config) is FAMILIES.get(name).Config and config.family == name
    assert from_dict(SystemConfig, to_dict(config)) == config
    family = make_family(config, torch.float64)
    a, b = (family.generate(8, 12, generator=generator(3)) for _ in range(2))
    assert torch.equal(a.y, b.y) and a.y.shape == (8, 13, family.output_dim) and a.family == name
    assert a.input_dim == family.input_dim and (a.y.abs() <= config.max_abs).all()
    with pytest.raises(MopError, match="unknown config key"):
        apply_overrides(config, ["no_such_knob=1"])


@pytest.mark.parametrize("name", FAMILY_NAMES)
def test_every_family_state_space_runs_the_ekf(name):
    traj = make_family(SystemConfig(family=name), torch.float64).generate(4, 10, generator=generator(1))
    model = state_space_of(traj)
    assert model.m0.shape == (4, make_family(SystemConfig(family=name)).state_dim)
    yhat = make_predictor("ekf").predict(traj)
    assert yhat.shape == traj.y.shape and torch.isfinite(yhat).all()


def _trajectories_for(name: str, tiny_run_family) -> object:
    """A batch the predictor accepts: learned ones their run's family, system-aware ones the first family
    whose state space they can use."""
    if is_learned(name):
        return tiny_run_family
    candidates = FAMILY_NAMES if needs_system(name) else ["linear"]
    for family in candidates:
        traj = make_family(SystemConfig(family=family), torch.float64).generate(5, 12, generator=generator(2))
        try:
            make_predictor(name, shared={"system": SystemConfig(family=family)}).predict(traj)
            return traj
        except MopError:
            continue
    pytest.fail(f"predictor {name} runs on no registered family")


@pytest.mark.parametrize("name", PREDICTORS.names())
def test_every_predictor_is_causal(name, tiny_run):
    """yhat[:, t] uses y[:, :t] only: changing the last output changes no prediction."""
    tiny = make_family(SystemConfig(state_dim=2, output_dim=2), torch.float32).generate(
        5, 12, generator=generator(2)
    )
    traj = _trajectories_for(name, tiny)
    family = SystemConfig(family=traj.family or "linear")  # the Bayes mixture's family: the test systems'
    options = {"run_dir": str(tiny_run)} if is_learned(name) else {"seed": 0, "system": family}
    predictor = make_predictor(name, shared=options)
    yhat = predictor.predict(traj)
    assert yhat.shape == traj.y.shape and torch.isfinite(yhat).all()
    later = dataclasses.replace(traj, y=traj.y.clone())
    later.y[:, -1] += 3.0
    torch.testing.assert_close(make_predictor(name, shared=options).predict(later), yhat)
    if PREDICTORS.meta(name).get("gaussian") and not is_learned(name):  # the variance is causal too
        mean, var = predictor.predict_distribution(traj)
        _, var_later = make_predictor(name, shared=options).predict_distribution(later)
        torch.testing.assert_close(var_later, var)
        assert var.shape == yhat.shape and (var > 0).all()


def test_system_aware_predictors_refuse_data_without_a_family():
    from mop.systems import Trajectories

    with pytest.raises(MopError, match="carry no system family"):
        make_predictor("kalman").predict(Trajectories(y=torch.zeros(2, 5, 3)))


def test_a_broken_plugin_package_is_one_line(monkeypatch):
    """An installed package whose entry point fails to import is named in one MopError, not a traceback."""
    import importlib.metadata

    class Broken:
        name, value, group = "pendulum", "broken_pkg.pendulum", "mop.families"

        def load(self):
            raise ModuleNotFoundError("No module named 'broken_pkg'")

    monkeypatch.setattr(importlib.metadata, "entry_points", lambda group: [Broken()])
    registry = Registry("system family", group="mop.families")
    with pytest.raises(MopError, match="plug-in 'broken_pkg.pendulum' .*ModuleNotFoundError"):
        registry.get("pendulum")
