"""The system-identification experiment files and the simulation analysis / RMSE measures they use."""

import types
from pathlib import Path

import numpy as np
import pytest
import torch

from mop.config import SystemConfig
from mop.experiments.analyses import ANALYSES
from mop.experiments.files import load_experiment
from mop.experiments.measures import measure_value
from mop.experiments.spec import Condition, Measure
from mop.predictors import make_predictor, simulate
from mop.systems import generator, make_family

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


@pytest.mark.parametrize("name", ["lti_siso.toml", "wiener_hammerstein.toml"])
def test_experiment_files_list_the_identifiers_that_use_inputs(name):
    exp = load_experiment(EXAMPLES / name)
    assert {"mop", "arx", "arx-10-offset", "n4sid-kf", "last"} <= set(exp.predictors)
    assert exp.presets["small"]["model.arx_order"] > 0  # MOP starts from ARX with the inputs
    assert "simulation" in exp.analyses and exp.conditions[0].context == 400


def test_simulation_analysis_and_rmse_measures_against_numpy():
    traj = make_family(SystemConfig(family="lti-siso", max_order=3), torch.float64).generate(
        5, 60, generator=generator(0)
    )
    preds = [make_predictor("arx"), make_predictor("last")]
    errors = {p.name: (p.predict(traj) - traj.y).norm(dim=-1).numpy() for p in preds}
    result = types.SimpleNamespace(
        traj=traj, errors=errors, condition=Condition("test", context=55), extras={}
    )
    result.extras.update(ANALYSES.get("simulation")(result, preds, "last"))
    for p in preds:
        sim = simulate(p, traj, 55).numpy()
        ref = np.sqrt(((sim - traj.y[:, 55:].numpy()) ** 2).mean(axis=(1, 2))).mean()
        got = measure_value(Measure("simulation_rmse", predictor=p.name), {"test": result}, "last", 0)
        np.testing.assert_allclose(got, ref, rtol=1e-12)
        yhat = p.predict(traj).numpy()
        one = np.sqrt(((yhat - traj.y.numpy())[:, 55:] ** 2).mean(axis=(1, 2))).mean()
        got = measure_value(Measure("one_step_rmse", predictor=p.name), {"test": result}, "last", 0)
        np.testing.assert_allclose(got, one, rtol=1e-10)
        got = measure_value(Measure("rmse", predictor=p.name, window=(55, None)), {"test": result}, "last", 0)
        np.testing.assert_allclose(got, one, rtol=1e-10)
        record = np.sqrt(((yhat - traj.y.numpy())[:, 50:] ** 2).mean(axis=(1, 2))).mean()  # t >= 50
        got = measure_value(Measure("one_step_rmse_record", predictor=p.name), {"test": result}, "last", 0)
        np.testing.assert_allclose(got, record, rtol=1e-10)


def test_a_free_run_that_diverges_on_one_system_makes_the_simulation_rmse_diverged_not_the_others_mean():
    """One system's simulation NaN (a free run whose recursion broke) or inf: the simulation RMSE over systems
    is inf with the count of diverged systems, and the table says "diverged", where the mean over the
    systems that stayed finite would hide it."""
    from mop.experiments.analyses import _simulation_table

    traj = make_family(SystemConfig(family="lti-siso", max_order=3), torch.float64).generate(
        5, 60, generator=generator(0)
    )
    arx = make_predictor("arx")

    class Breaking:
        name = "breaking"

        def predict(self, t):
            return arx.predict(t)

        def simulate(self, t, c):
            sim = simulate(arx, t, c).clone()
            sim[2, -1] = float("nan")
            return sim

    preds = [arx, Breaking()]
    errors = {p.name: (p.predict(traj) - traj.y).norm(dim=-1).numpy() for p in preds}
    result = types.SimpleNamespace(
        traj=traj, errors=errors, condition=Condition("test", context=55), extras={}
    )
    extras = ANALYSES.get("simulation")(result, preds, "arx")
    table = extras["simulation"]["rmse"]
    assert table["breaking"]["simulation_rmse"] == float("inf") and table["breaking"]["diverged_systems"] == 1
    assert np.isfinite(table["arx"]["simulation_rmse"]) and "diverged_systems" not in table["arx"]
    markdown = _simulation_table(extras)
    assert "| breaking | " in markdown and "diverged (1 systems)" in markdown
