"""The records run's held-out check (mop.recipe.selection) against what a test of the record could surprise
it with: the test's initialization window, a free run as long as the record, the better of the two linear
models `mop fit arx` and `mop fit n4sid`, and the network's other reading; what it keeps is what loads."""

import dataclasses
import math

import numpy as np
import pytest

import mop
from mop.config import DataConfig
from mop.identify.narx_model import KIND as FEATURE
from mop.identify.select import fit
from mop.recipe import selection
from mop.recipe.fit import fit_record
from mop.record import Record
from mop.records import simulate_all
from mop.runs import load_config
from mop.train.records import TrainingRecords

pytestmark = pytest.mark.usefixtures("one_thread")
# a records run trained for simulation: each window's outputs from a random step s >= 10 read as missing
SIMULATION = ["model.observation_mask=true", "model.forecast_mode=gap", "train.simulate_after=10"]


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


def test_the_long_run_covers_the_records_end_and_scores_a_slow_divergence_the_held_out_tail_misses():
    record = output_error_plant(1000)
    split = TrainingRecords((record,)).split(DataConfig(path="oe"))
    ((y, u, init),) = selection.long_run_stretches(split, 50)
    assert init == 50 and len(y) == 1000 and np.array_equal(y, record.y) and np.array_equal(u, record.u)
    long = TrainingRecords((output_error_plant(5000),)).split(DataConfig(path="oe"))
    ((y, _, _),) = selection.long_run_stretches(long, 50)
    assert len(y) == selection.LONG_RUN  # capped: the record's last LONG_RUN steps
    arx = fit("arx", [(record.y, record.u)])
    grow = 1.01 / arx.info["pole_radius"]  # its slowest mode grows 1% a step
    unstable = dataclasses.replace(arx, model=dataclasses.replace(arx.model, A=grow * arx.model.A))
    held_out, long_run = selection.held_out_stretches(split, 50), selection.long_run_stretches(split, 50)
    scores = selection._scores(unstable, held_out, long_run)
    assert math.isfinite(scores["held_out"]) and scores["long_run"] == math.inf == scores["score"]
    steady = selection._scores(arx, held_out, long_run)
    assert steady["score"] == pytest.approx((steady["held_out"] + steady["long_run"]) / 2)


def test_n4sid_is_kept_where_it_simulates_the_record_better_than_the_arx(tmp_path):
    """A ruined network (learning rate 3, a Gaussian read-out: no gain to scale) on an output-error plant:
    the run keeps the fitted N4SID, which scores better than the fitted ARX, and predicts exactly what
    `mop fit n4sid` fitted on the whole record predicts."""
    record = output_error_plant()
    records = TrainingRecords((record,), source="oe")
    over = ["train.steps=30", "train.lr=3", "model.readout=gaussian"]
    chosen = fit_record(tmp_path / "run", records, overrides=over, progress=False).selection
    assert (
        chosen["linear_models"]["n4sid"]["score"] < chosen["linear_models"]["arx"]["score"]
        and chosen["kept"] == "n4sid"
    )
    loaded, refit = mop.load(tmp_path / "run"), fit("n4sid", [record], source="oe")
    data = [(record.y, record.u)]
    np.testing.assert_array_equal(simulate_all(loaded, data, 50)[0], simulate_all(refit, data, 50)[0])


def test_a_run_trained_for_simulation_is_scored_in_both_readings_and_loads_the_kept_one(tmp_path):
    """The records recipe trained for simulation (SIMULATION, read as gaps): the check scores the
    network reading its simulated outputs as missing and feeding its predictions back, at every gain; the
    lowest mean score is kept, and the loaded run simulates the held-out data and the long run at exactly
    that score, in that reading."""
    records = TrainingRecords((cubic_plant(800),), source="cubic")
    over = ["train.steps=150", *SIMULATION]
    run = fit_record(tmp_path / "run", records, overrides=over, progress=False)
    config, chosen = load_config(run.run_dir), run.selection
    assert config.train.simulate_after > 0 and config.model.forecast_mode == "gap"
    assert set(chosen["network"]) == {"gap", "rollout"}
    scores = {
        (r, g): s["score"]
        for r, by in chosen["network"].items()
        for g, s in zip(chosen["gains"], by, strict=True)
    }
    scores.update({(k, None): s["score"] for k, s in chosen["linear_models"].items()})
    best = min(scores.values())
    assert chosen["kept"] == "network" and scores[(chosen["reading"], chosen["gain"])] == best
    loaded = mop.load(run.run_dir)
    assert loaded.predictor_.cfg.forecast_mode == chosen["reading"]
    record = TrainingRecords((cubic_plant(800),)).split(config.data)
    n = selection.init_window(record)
    held_out, long_run = selection.held_out_stretches(record, n), selection.long_run_stretches(record, n)
    assert selection._scores(loaded, held_out, long_run)["score"] == pytest.approx(best, rel=1e-6)
    assert "held-out check (mean RMSE" in selection.selection_line(chosen)


def test_a_transformer_trained_for_simulation_is_weighed_at_its_feature_alone_and_as_trained(tmp_path):
    """model.arch=gpt trained for simulation (SIMULATION): its correction is weighed at gain 0 (its feature
    alone) and 1 (as trained) only, in both readings, where one trained one step ahead is weighed at every
    gain of mop.recipe.shrink.GAINS (test_budget_selection); the kept candidate is the lowest of those."""
    records = TrainingRecords((cubic_plant(800),), source="cubic")
    over = ["model.arch=gpt", "train.steps=30", *SIMULATION]
    run = fit_record(tmp_path / "run", records, overrides=over, progress=False)
    chosen = run.selection
    assert load_config(run.run_dir).model.rls_order > 0  # a feature whose correction has gains
    assert chosen["gains"] == [0.0, 1.0] and set(chosen["network"]) == {"gap", "rollout"}
    assert all(len(by) == 2 for by in chosen["network"].values())
    scores = [s["score"] for by in chosen["network"].values() for s in by]
    scores += [s["score"] for s in chosen["linear_models"].values()]
    kept = (
        chosen["network"][chosen["reading"]][chosen["gains"].index(chosen["gain"])]
        if chosen["kept"] == "network"
        else chosen["linear_models"][chosen["kept"]]
    )
    assert kept["score"] == min(scores)


@pytest.mark.parametrize("arch", ["deep-lru", "gru"])
def test_a_recurrent_records_run_trains_without_a_feature_and_makes_the_check(arch, tmp_path):
    """model.arch=deep-lru (or gru) reads no input features: the records recipe plans its model size and steps
    with no ARX feature, and the run still makes the held-out check against the fitted ARX and N4SID (one
    gain: there is no feature to scale towards); what it keeps is what loads, at its scores."""
    records = TrainingRecords((cubic_plant(800),), source="cubic")
    over = [f"model.arch={arch}", "train.steps=60", *SIMULATION]
    run = fit_record(tmp_path / "run", records, overrides=over, progress=False)
    config, chosen = load_config(run.run_dir), run.selection
    assert config.model.arch == arch and config.model.rls_order == config.model.arx_order == 0
    assert (config.model.num_layers, config.model.width) == (1, 32)  # the recipe's RECORDED_MODEL
    assert chosen["gains"] == [1.0] and set(chosen["network"]) == {"gap", "rollout"}
    # the fitted ARX and N4SID, and the recipe's feature where it is a cubic NARX (or a longer ARX)
    assert {"arx", "n4sid"} <= set(chosen["linear_models"]) <= {"arx", "n4sid", FEATURE}
    record = TrainingRecords((cubic_plant(800),)).split(config.data)
    n = selection.init_window(record)
    held_out, long_run = selection.held_out_stretches(record, n), selection.long_run_stretches(record, n)
    kept = chosen["linear_models"][chosen["kept"]] if chosen["kept"] != "network" else None
    best = kept["score"] if kept else chosen["network"][chosen["reading"]][0]["score"]
    assert selection._scores(mop.load(run.run_dir), held_out, long_run)["score"] == pytest.approx(
        best, rel=1e-6
    )
