"""Experiments as data: every registered experiment builds its runs' configs under every preset, claims
are checked against hand-computed numbers, experiment files equal their Python twins, bad ones are refused."""

import json

import numpy as np
import pytest

from mop.config import RunConfig
from mop.errors import MopError
from mop.experiments import EXPERIMENTS, PRESETS, get_experiment, get_preset, run_config
from mop.experiments.figures import figure_names
from mop.experiments.files import experiment_from_dict, load_experiment
from mop.experiments.planning import config_hash
from mop.experiments.reporting import check_claim
from mop.experiments.results import ConditionResult
from mop.experiments.spec import Claim, Condition, Experiment, Measure
from mop.metrics import mse_ratio_ci
from mop.predictors import PREDICTORS


@pytest.mark.parametrize("name", EXPERIMENTS.names())
@pytest.mark.parametrize("preset", list(PRESETS))
def test_every_experiment_builds_its_run_configs(name, preset):
    exp = get_experiment(name)
    assert exp.reference in exp.predictors and all(p in PREDICTORS for p in exp.predictors)
    for condition in exp.conditions_for(preset):
        cfg = run_config(exp, preset, seed=3, condition=condition)
        assert isinstance(cfg, RunConfig) and cfg.train.seed == 3
        named = "model.context" in {**exp.train, **exp.presets.get(preset, {})}  # the class models: 500
        assert cfg.model.context == cfg.train.horizon or named and cfg.model.context > cfg.train.horizon


def test_an_experiment_naming_no_reference_panel_or_figures_gets_the_registered_defaults():
    """The defaults come from the entries' metadata: the KF as reference, the experiment's first learned
    predictor, the reference and RLS in the panel, the error figure; as the literal defaults were before."""
    exp = Experiment("x", "x", {}, predictors=("zero", "gru", "mop", "kalman"))
    assert (exp.reference, exp.panel, figure_names(exp)) == ("kalman", ("gru", "", "rls"), ("error",))
    switching = get_experiment("switching")  # names none of the three
    assert (switching.reference, switching.panel, figure_names(switching)) == (
        "kalman",
        ("mop", "", "rls"),
        ("error",),
    )
    given = Experiment("y", "y", {}, predictors=("ekf",), reference="ekf", panel=("ekf",), figures=())
    assert (given.reference, given.panel, figure_names(given)) == ("ekf", ("ekf",), ())
    assert Experiment("z", "z", {}, predictors=("kalman", "rls")).panel == ("", "rls")  # nothing learned


def test_paper_preset_is_the_papers_setting():
    p = get_preset("paper")
    assert (p.model.num_layers, p.model.num_heads, p.model.width) == (12, 8, 256)
    t = p.train
    assert (t.num_source_systems, t.horizon, t.steps, t.batch_size) == (20000, 50, 10000, 64)
    assert p.num_test_systems == 1000


def test_runs_are_shared_by_config_hash():
    """switching tests the plain linear model: same training config, so the same run directory."""
    linear, switching = get_experiment("linear"), get_experiment("switching")
    assert config_hash(run_config(linear, "small")) == config_hash(run_config(switching, "small"))
    assert config_hash(run_config(linear, "small")) != config_hash(run_config(linear, "small", seed=1))
    (condition,) = switching.conditions
    assert condition.horizon == 100 and condition.system == {"family": "switching", "switch_time": 50}


def test_overrides_layer_on_top():
    exp = get_experiment("calibration")
    cfg = run_config(exp, "smoke", condition=exp.conditions[1], overrides=["model.num_layers=3"])
    assert (
        cfg.model.readout == "gaussian" and cfg.system.family == "colored-noise" and cfg.model.num_layers == 3
    )
    with pytest.raises(MopError, match="unknown config key"):
        run_config(exp, "smoke", overrides=["model.bogus=1"])


def test_unknown_names():
    with pytest.raises(MopError, match="unknown experiment"):
        get_experiment("nope")
    with pytest.raises(MopError, match="unknown preset"):
        get_preset("huge")


def _result(name: str, errors: dict, **extras) -> ConditionResult:
    return ConditionResult(Condition(name), None, errors, {}, extras)


def test_claims_against_hand_computed_numbers():
    rng = np.random.default_rng(0)
    e_mop, e_kf = rng.random((40, 11)) + 0.2, rng.random((40, 11))
    results = {
        "a": _result("a", {"mop": e_mop, "kalman": e_kf}),
        "b": _result("b", {"mop": e_kf, "kalman": e_kf}),
    }
    ratio, low, high = mse_ratio_ci(e_mop, e_kf, 5, 11, seed=0)
    claim = Claim("ratio", Measure("mse_ratio", window=(5, None)), "<=", ratio)
    assert check_claim(claim, results, "kalman", 0) == {
        "claim": "ratio",
        "measure": "MSE mop/kalman over t in [5,T)",
        "value": ratio,
        "op": "<=",
        "threshold": ratio,
        "holds": True,
    }
    above = Claim("low", Measure("mse_ratio", window=(5, None), bound="low"), ">", low)
    assert check_claim(above, results, "kalman", 0)["holds"] is False  # low > low fails
    across = Claim("max", Measure("mse_ratio", window=(5, None), condition="*"), "<", 1.0)
    assert check_claim(across, results, "kalman", 0)["value"] == pytest.approx(max(ratio, 1.0))
    two = Claim(
        "vs",
        Measure("mean_error", window=(1, None)),
        ">",
        Measure("mean_error", window=(1, None), condition="b"),
    )
    checked = check_claim(two, results, "kalman", 0)
    assert (checked["value"], checked["threshold"]) == pytest.approx(
        (e_mop[:, 1:].mean(), e_kf[:, 1:].mean())
    )
    assert checked["holds"] is True  # e_mop = e_kf-like draws + 0.2
    band = Claim("cov", Measure("mean_error", window=(0, None)), "between", (0.0, 0.1))
    assert check_claim(band, results, "kalman", 0)["holds"] is False
    assert (
        check_claim(Claim("i", Measure("mean_error", window=(0, None))), results, "kalman", 0)["holds"]
        is None
    )


EXAMPLE = {
    "name": "mine",
    "title": "a user's experiment",
    "train": {"system.family": "linear", "train.steps": 5},
    "predictors": ["mop", "kalman", "rls"],
    "conditions": [{"name": "test", "horizon": 30}, {"name": "noisy", "system": {"noise_var_v": 0.1}}],
    "claims": [
        {
            "text": "close",
            "measure": {"metric": "mse_ratio", "window": [20, 31]},
            "op": "<",
            "threshold": 1.2,
        },
        {"text": "band", "measure": {"metric": "mean_error"}, "op": "between", "threshold": [0.1, 1.0]},
        {
            "text": "vs",
            "measure": {"metric": "mean_error"},
            "op": "<",
            "threshold": {"metric": "mean_error", "predictor": "rls"},
        },
    ],
}


def test_experiment_file_equals_its_python_twin(tmp_path):
    twin = Experiment(
        name="mine",
        title="a user's experiment",
        train={"system.family": "linear", "train.steps": 5},
        predictors=("mop", "kalman", "rls"),
        conditions=(Condition("test", horizon=30), Condition("noisy", system={"noise_var_v": 0.1})),
        claims=(
            Claim("close", Measure("mse_ratio", window=(20, 31)), "<", 1.2),
            Claim("band", Measure("mean_error"), "between", (0.1, 1.0)),
            Claim("vs", Measure("mean_error"), "<", Measure("mean_error", predictor="rls")),
        ),
    )
    path = tmp_path / "mine.json"
    path.write_text(json.dumps(EXAMPLE))
    assert load_experiment(path) == twin
    toml = tmp_path / "mine.toml"
    toml.write_text(
        'name = "mine"\ntitle = "a user\'s experiment"\npredictors = ["mop", "kalman", "rls"]\n'
        '[train]\n"system.family" = "linear"\n"train.steps" = 5\n'
        '[[conditions]]\nname = "test"\nhorizon = 30\n'
        '[[conditions]]\nname = "noisy"\nsystem = { noise_var_v = 0.1 }\n'
        '[[claims]]\ntext = "close"\nmeasure = { metric = "mse_ratio", window = [20, 31] }\n'
        'op = "<"\nthreshold = 1.2\n'
        '[[claims]]\ntext = "band"\nmeasure = { metric = "mean_error" }\n'
        'op = "between"\nthreshold = [0.1, 1.0]\n'
        '[[claims]]\ntext = "vs"\nmeasure = { metric = "mean_error" }\nop = "<"\n'
        'threshold = { metric = "mean_error", predictor = "rls" }\n'
    )
    assert load_experiment(toml) == twin


@pytest.mark.parametrize(
    "change, message",
    [
        ({"name": None}, "missing required field 'name'"),
        ({"claims": [{"text": "x", "measure": {"metric": "mse_ratio"}, "op": "~"}]}, "op must be one of"),
        ({"claims": [{"text": "x", "measure": {"metric": "mse_ratio", "bogus": 1}}]}, "unknown config key"),
        ({"conditions": [{"name": "a"}, {"name": "a"}]}, "condition names repeat"),
        ({"typo": 1}, "unknown config key 'typo'"),
    ],
)
def test_bad_experiment_files_are_refused(tmp_path, change, message):
    data = {**EXAMPLE, **change}
    data = {k: v for k, v in data.items() if v is not None}
    with pytest.raises(MopError, match=message):
        experiment_from_dict(data)
    bad = tmp_path / "bad.toml"
    bad.write_text("name = [")
    with pytest.raises(MopError, match="not valid TOML"):
        load_experiment(bad)


@pytest.mark.parametrize(
    "preset, flag, gru",
    [("paper", None, True), ("small", None, False), ("smoke", None, False), ("smoke", True, True)]
    + [("paper", False, False)],
)
def test_which_learned_baselines_a_preset_trains_is_their_metadata(tmp_path, preset, flag, gru):
    """The GRU declares the presets that skip it (skip_presets); --with gru / --without gru override; the
    runner names no predictor. Same choice as the presets' former train_gru
    (paper on, small and smoke off)."""
    from mop.experiments.planning import Session, wanted

    exp = get_experiment("linear")
    session = Session(exp, preset, 0, tmp_path, [], False, {} if flag is None else {"gru": flag})
    names = wanted(session, exp.conditions[0])
    assert ("gru" in names) is gru and "mop" in names and "kalman" in names
    assert PREDICTORS.meta("n4sid-kf")["preset_options"]["small"] == {"every": 10}


def test_a_new_analysis_and_measure_render_themselves(tmp_path, tiny_smoke, monkeypatch):
    """An analysis and a measure registered outside the runner reach eval.json and report.md through their
    own metadata (markdown, to_json, sections, describe): the runner special-cases neither."""
    from mop.experiments.analyses import ANALYSES
    from mop.experiments.measures import MEASURES
    from mop.experiments.runner import run_experiment

    def last_error(result, predictors, reference):
        return {"last_error": {n: float(e[:, -1].mean()) for n, e in result.errors.items()}}

    def worst(results):
        return {"worst_last_error": max(v for r in results.values() for v in r.extras["last_error"].values())}

    def read(measure, result, reference, seed):
        return result.extras["last_error"][measure.predictor]

    for registry, name, entry, meta in [
        (
            ANALYSES,
            "last-error",
            last_error,
            {
                "markdown": lambda extras: f"LAST {sorted(extras['last_error'])}\n",
                "to_json": worst,
                "sections": lambda entries: [f"WORST {entries['worst_last_error']:.6f}\n"],
            },
        ),
        (MEASURES, "last", read, {"describe": lambda m, ref: f"last error of {m.predictor}"}),
    ]:  # registered for this test only
        monkeypatch.setitem(registry._entries, name, entry)
        monkeypatch.setitem(registry._meta, name, meta)
    exp = Experiment(
        name="t",
        title="t",
        train={"system.family": "linear"},
        predictors=("kalman", "zero"),
        conditions=(Condition("a"), Condition("b", system={"noise_var_v": 0.5})),
        analyses=("last-error",),
        figures=(),
        panel=("kalman",),
        claims=(Claim("kalman's last error", Measure("last", predictor="kalman", condition="b")),),
    )
    report = run_experiment(exp, "smoke", tmp_path / "t", progress=False).read_text()
    data = json.loads((tmp_path / "t" / "eval.json").read_text())
    errors = {c: data["conditions"][c]["predictors"] for c in ("a", "b")}
    assert data["conditions"]["b"]["last_error"]["kalman"] == pytest.approx(
        errors["b"]["kalman"]["error"][-1]
    )
    worst_seen = max(p["error"][-1] for c in errors.values() for p in c.values())
    assert data["worst_last_error"] == pytest.approx(worst_seen)
    assert report.count("LAST ['kalman', 'zero']") == 2 and f"WORST {data['worst_last_error']:.6f}" in report
    (claim,) = data["claims"]
    assert claim["measure"] == "last error of kalman" and "last error of kalman" in report
    assert claim["value"] == data["conditions"]["b"]["last_error"]["kalman"]
