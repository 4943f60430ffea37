"""The experiment registry and presets: every entry builds a valid RunConfig, unknown names are refused."""

import pytest

from mop.config import RunConfig
from mop.errors import MopError
from mop.experiments import EXPERIMENTS, PRESETS, get_experiment, get_preset, run_config


@pytest.mark.parametrize("name", list(EXPERIMENTS))
@pytest.mark.parametrize("preset", list(PRESETS))
def test_every_experiment_builds_a_run_config(name, preset):
    exp = get_experiment(name)
    cfg = run_config(exp, preset, seed=3)
    assert isinstance(cfg, RunConfig) and cfg.train.seed == 3
    assert cfg.system == exp.train_system and cfg.model.context == cfg.train.horizon
    assert exp.reference in exp.baselines


def test_paper_preset_is_the_papers_setting():
    p = get_preset("paper")
    assert (p.model.num_layers, p.model.num_heads, p.model.width) == (12, 8, 256)
    t = p.train
    assert (t.num_source_systems, t.horizon, t.steps, t.batch_size) == (20000, 50, 10000, 64)
    assert p.num_test_systems == 1000


def test_switching_uses_linear_model_and_long_test():
    exp = get_experiment("switching")
    assert exp.train_system.family == "linear" and exp.test_horizon == 100
    assert exp.test_system.switch_time == 50
    assert {"kalman", "kalman-switch"} <= set(exp.baselines)


def test_gru_config_and_unknown_names():
    assert run_config(get_experiment("linear"), "small", arch="gru").model.arch == "gru"
    assert run_config(get_experiment("calibration"), "smoke").model.readout == "gaussian"
    with pytest.raises(MopError, match="unknown experiment"):
        get_experiment("nope")
    with pytest.raises(MopError, match="unknown preset"):
        get_preset("huge")
