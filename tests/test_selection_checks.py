"""The records run's held-out check (mop.recipe.selection) against what a test of the record could surprise
it with: the test's initialization window, a free run as long as the record, and the better of the two
linear models `mop fit arx` and `mop fit n4sid`."""

import dataclasses
import shutil

import numpy as np
import pytest

import mop
from mop.config import DataConfig
from mop.identify.select import fit
from mop.recipe import selection
from mop.recipe.fit import fit_record
from mop.recipe.layers import scratch_config
from mop.recipe.training import train
from mop.record import Record
from mop.records import simulate_all
from mop.train.records import TrainingRecords

pytestmark = pytest.mark.usefixtures("one_thread")


def output_error_plant(steps: int = 1500, seed: int = 0, noise: float = 0.8) -> Record:
    """x_{t+1} = 1.5 x_t - 0.7 x_{t-1} + u_t, y_t = x_t + noise e_t: white noise on the output only, which an
    ARX (equation error) fits with a bias and N4SID does not, so N4SID simulates it better."""
    rng = np.random.default_rng(seed)
    u = rng.normal(size=steps)
    x = np.zeros(steps)
    for t in range(2, steps):
        x[t] = 1.5 * x[t - 1] - 0.7 * x[t - 2] + u[t - 1]
    return Record(y=x + noise * rng.normal(size=steps), u=u, name="oe")


def cubic_plant(steps: int = 1500) -> Record:
    """y_t = 0.6 y_{t-1} + 0.8 tanh(3 u_{t-1})^3: a static nonlinearity no linear model follows."""
    u = np.random.default_rng(1).normal(size=steps)
    y = np.zeros(steps)
    for t in range(1, steps):
        y[t] = 0.6 * y[t - 1] + 0.8 * np.tanh(3 * u[t - 1]) ** 3
    return Record(y=y, u=u, name="cubic")


def test_the_held_out_check_starts_from_the_records_init_window():
    record = output_error_plant(1000)
    split = TrainingRecords((dataclasses.replace(record, init_window=5),)).split(DataConfig(path="oe"))
    ((y, _, init),) = selection.held_out_stretches(split)
    assert selection.init_window(split) == init == 5 and len(y) == 5 + len(split.val_parts[0])
    plain = TrainingRecords((record,)).split(DataConfig(path="oe"))
    assert selection.init_window(plain) == selection.INIT_WINDOW == selection.held_out_stretches(plain)[0][2]


def test_a_free_run_that_leaves_the_record_over_its_length_diverges():
    record = output_error_plant(600)
    split = TrainingRecords((record,)).split(DataConfig(path="oe"))
    arx = fit("arx", [(record.y, record.u)])
    assert not selection.diverges_over_records(arx, split, 50)
    grow = 1.02 / arx.info["pole_radius"]  # its slowest mode grows 2% a step
    unstable = dataclasses.replace(arx, model=dataclasses.replace(arx.model, A=grow * arx.model.A))
    sim = simulate_all(unstable, [(record.y, record.u)], 50)[0]
    assert np.abs(sim[:50]).max() < 5 * np.abs(record.y).max()  # in range over a held-out tail's first steps
    assert selection.diverges_over_records(unstable, split, 50)


def test_n4sid_is_kept_where_it_simulates_the_held_out_data_better_than_the_arx(tmp_path):
    """A ruined network (learning rate 3, a Gaussian read-out: no gain to scale) on an output-error plant:
    the run keeps the fitted N4SID, which simulates the held-out tail better than the fitted ARX, and
    predicts exactly what `mop fit n4sid` fitted on the whole record predicts."""
    record = output_error_plant()
    records = TrainingRecords((record,), source="oe")
    over = ["train.steps=30", "train.lr=3", "model.readout=gaussian"]
    run = fit_record(tmp_path / "run", records, overrides=over, progress=False)
    chosen = run.selection
    assert chosen["linear_rmse"]["n4sid"] < chosen["linear_rmse"]["arx"] and chosen["kept"] == "n4sid"
    loaded, refit = mop.load(tmp_path / "run"), fit("n4sid", [record], source="oe")
    data = [(record.y, record.u)]
    np.testing.assert_array_equal(simulate_all(loaded, data, 50)[0], simulate_all(refit, data, 50)[0])


def test_a_candidate_whose_free_run_over_the_record_diverges_is_passed_over(tmp_path, monkeypatch):
    """The held-out ranking is followed down to the first candidate whose free run over the whole record
    stays in range: where every reading of the network leaves it, a linear model is kept, and the line says
    which were passed over."""
    given = TrainingRecords((cubic_plant(),))
    config, records, record = scratch_config(None, None, given, ["train.steps=150"], None)
    trained = train(config, tmp_path / "plain", progress=False, records=records)
    shutil.copytree(trained, tmp_path / "run")
    plain = selection.select_against_linear(trained, config, record)
    assert plain["kept"] == "network" and plain["passed_over"] == []
    checked = []

    def network_diverges(predictor, record, n):
        checked.append(type(predictor).__name__)
        return type(predictor).__name__ == "LearnedPredictor"

    monkeypatch.setattr(selection, "diverges_over_records", network_diverges)
    chosen = selection.select_against_linear(tmp_path / "run", config, record)
    best_linear = min(chosen["linear_rmse"].values())
    assert chosen["kept"] in ("arx", "n4sid") and chosen["linear_rmse"][chosen["kept"]] == best_linear
    ahead = [
        g for g, s in zip(chosen["gains"], chosen["network_rmse_by_gain"], strict=True) if s <= best_linear
    ]
    assert ahead and chosen["passed_over"] == [f"network at gain {g:g}" for g in sorted(ahead, reverse=True)]
    assert checked.count("LearnedPredictor") == len(ahead)
    assert "whole record diverged: network at gain" in selection.selection_line(chosen)
