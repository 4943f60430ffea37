"""mop.experiments.validate: every mistake of an experiment file is one line before any training.

Each case breaks one field of a valid experiment; `mop reproduce FILE` must exit 2 with one line naming the
problem, without training (mop.train.train is replaced by a tripwire) and without creating the output folder.
"""

import copy
import json

import pytest

import mop.experiments.planning
import mop.train
from mop.cli import main
from mop.experiments import EXPERIMENTS, PRESETS, get_experiment
from mop.experiments.files import load_experiment
from mop.experiments.validate import validate_experiment

BASE = {
    "name": "t",
    "title": "a test experiment",
    "predictors": ["mop", "kalman", "rls"],
    "reference": "kalman",
    "train": {"system.family": "linear"},
    "conditions": [{"name": "test", "horizon": 30}],
    "claims": [
        {"text": "c", "measure": {"metric": "mse_ratio", "window": [20, 31]}, "op": "<", "threshold": 1.5}
    ],
}


def _set(path: str, value):
    def change(data):
        *keys, leaf = path.split("/")
        node = data
        for key in keys:
            node = node[int(key)] if isinstance(node, list) else node[key]
        node[leaf] = value

    return change


CASES = {
    "unknown predictor": (_set("predictors", ["mop", "kalmann"]), "unknown predictor 'kalmann'"),
    "unknown reference": (_set("reference", "kf"), "unknown predictor 'kf'"),
    "unknown figure": (_set("figures", ["errors"]), "unknown figure 'errors'"),
    "unknown analysis": (_set("analyses", ["calib"]), "unknown analysis 'calib'"),
    "unknown metric": (_set("claims/0/measure/metric", "mse_ratioo"), "unknown metric 'mse_ratioo'"),
    "unknown condition": (_set("claims/0/measure/condition", "nope"), "no condition 'nope'"),
    "measure predictor": (_set("claims/0/measure/predictor", "rlss"), "unknown predictor 'rlss'"),
    "not evaluated": (_set("claims/0/measure/predictor", "last"), "'last' is not evaluated"),
    "threshold abc": (_set("claims/0/threshold", "abc"), "threshold must be a number"),
    "window [20]": (_set("claims/0/measure/window", [20]), "window must be a list of 2 values"),
    "window of strings": (_set("claims/0/measure/window", ["a", "b"]), "window must be a list of 2"),
    "between a number": (_set("claims/0/op", "between"), "op 'between' needs threshold [low, high]"),
    "conditions abc": (_set("conditions", "abc"), "conditions must be a list of tables"),
    "claims abc": (_set("claims", "abc"), "claims must be a list of tables"),
    "window beyond T": (_set("claims/0/measure/window", [40, 50]), "starts beyond T = 30"),
    "test system value": (_set("conditions/0/system", {"noise_var_w": "abc"}), "noise_var_w must be a"),
    "train value": (_set("train", {"train.lr": "abc"}), "train.lr must be a number, got 'abc'"),
    "train key": (_set("train", {"train.bogus": 1}), "unknown config key 'train.bogus'"),
    "family": (_set("train", {"system.family": "lineer"}), "lineer"),
    "coverage without analysis": (_set("claims/0/measure/metric", "coverage"), "needs the 'calibration'"),
    "level": (_set("claims/0/measure/level", 2), "level must be a number in (0, 1)"),
    "missing data file": (_set("conditions/0/data", "nope.csv"), "nope.csv does not exist"),
    "horizon type": (_set("conditions/0/horizon", "long"), "horizon must be an integer"),
    "too few forecast heads": (
        lambda d: d.update(
            analyses=["forecast"],
            train={"system.family": "linear", "model.horizons": 5, "model.forecast_mode": "direct"},
        ),
        "forecasts 10 steps, but model.horizons=5",
    ),
}

PLUGINS = {
    "raises": ("x = 1\nraise ValueError('boom')\n", "failed to import: ValueError: boom (line 2)"),
    "syntax": ("def broken(:\n", "SyntaxError at line 1"),
    "missing module": ("import not_a_module_xyz\n", "ModuleNotFoundError: No module named 'not_a_module"),
}


@pytest.fixture
def no_training(monkeypatch):
    def tripwire(*args, **kwargs):
        raise AssertionError("trained before the experiment was validated")

    monkeypatch.setattr(mop.train, "train", tripwire)
    monkeypatch.setattr(mop.experiments.planning, "train_model", tripwire)


def _fails_before_training(tmp_path, data, capsys, words):
    path = tmp_path / "exp.json"
    path.write_text(json.dumps(data))
    out = tmp_path / "out"
    assert main(["reproduce", str(path), "--preset", "smoke", "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1 and words in err, err
    assert not out.exists()


@pytest.mark.parametrize("case", CASES)
def test_a_mistake_is_one_line_before_training(case, tmp_path, capsys, no_training):
    change, words = CASES[case]
    data = copy.deepcopy(BASE)
    change(data)
    _fails_before_training(tmp_path, data, capsys, words)


@pytest.mark.parametrize("case", PLUGINS)
def test_a_broken_plugin_is_one_line(case, tmp_path, capsys, no_training):
    source, words = PLUGINS[case]
    (tmp_path / f"plugin_{case.replace(' ', '_')}.py").write_text(source)
    data = {**copy.deepcopy(BASE), "plugins": [f"plugin_{case.replace(' ', '_')}.py"]}
    _fails_before_training(tmp_path, data, capsys, words)


def test_the_valid_base_passes(tmp_path):
    path = tmp_path / "exp.json"
    path.write_text(json.dumps(BASE))
    validate_experiment(load_experiment(path), "smoke")


def test_one_predictor_as_a_string(tmp_path):
    """`predictors = "mop"` is the list ["mop"], not the letters m, o, p."""
    path = tmp_path / "exp.toml"
    path.write_text(
        'name = "t"\ntitle = "t"\npredictors = "mop"\nreference = "mop"\n'
        '[train]\n"system.family" = "linear"\n'
    )
    exp = load_experiment(path)
    assert exp.predictors == ("mop",)
    validate_experiment(exp, "smoke")


@pytest.mark.parametrize("preset", list(PRESETS))
def test_every_registered_experiment_is_valid(preset):
    for name in EXPERIMENTS.names():
        validate_experiment(get_experiment(name), preset)
