"""The records recipe's budget (a pure plan from minutes and the record's windows) and its held-out
comparison with the fitted linear models (never worse than `mop fit arx` and `mop fit n4sid`: the better of
them is kept, exactly, where it wins)."""

import dataclasses
import json
import math

import numpy as np
import pytest

import mop
from mop.cli import main
from mop.errors import MopError
from mop.identify import load as load_fitted
from mop.identify.select import fit
from mop.io import read_trajectories
from mop.recipe import selection
from mop.recipe.budget import MAX_EPOCHS, MIN_STEPS, NOMINAL_STEP_SECONDS, plan_steps
from mop.recipe.layers import training_config
from mop.recipe.selection import (
    SELECTION_FILE,
    held_out_stretches,
    select_against_linear,
    simulation_rmse,
    stretches_rmse,
)
from mop.recipe.shrink import GAINS
from mop.records import simulate_all
from mop.runs import load_config
from mop.train.records import recorded_data

pytestmark = pytest.mark.usefixtures("one_thread")


def arx_plant(path, steps=700, seed=0):
    """One record of y_t = 1.2 y_{t-1} - 0.5 y_{t-2} + 0.8 u_{t-1} + e_t: a linear ARX plant."""
    rng = np.random.default_rng(seed)
    u = rng.normal(size=steps)
    y = np.zeros(steps)
    for t in range(2, steps):
        y[t] = 1.2 * y[t - 1] - 0.5 * y[t - 2] + 0.8 * u[t - 1] + 0.05 * rng.normal()
    path.write_text("y0,u0\n" + "\n".join(f"{a:.8f},{b:.8f}" for a, b in zip(y, u, strict=True)) + "\n")
    return path


@pytest.mark.parametrize(
    "minutes, windows, batch", [(5, 58505, 64), (5, 872, 64), (0.5, 10**6, 64), (60, 10**5, 32)]
)
def test_the_plan_is_the_smaller_of_budget_and_record_never_below_the_minimum(minutes, windows, batch):
    plan = plan_steps(minutes, windows, batch)
    by_budget = int(minutes * 60 / NOMINAL_STEP_SECONDS)
    by_record = math.ceil(MAX_EPOCHS * windows / batch)
    assert plan.steps == max(MIN_STEPS, min(by_budget, by_record))
    assert plan.steps == plan_steps(minutes, windows, batch).steps  # pure: same inputs, same steps
    assert f"{plan.steps} steps" in plan.line(0.02)


def test_longer_records_and_budgets_train_longer_short_ones_keep_the_minimum():
    assert plan_steps(5, 800, 64).steps == MIN_STEPS
    assert plan_steps(5, 58505, 64).steps == 15000  # Silverbox's estimation part: the budget decides
    assert plan_steps(10, 58505, 64).steps == 30000
    assert plan_steps(5, 5000, 64).steps < plan_steps(5, 20000, 64).steps


@pytest.mark.parametrize("bad", ["0", "-1", "nan", "five"])
def test_a_bad_budget_is_one_line_before_any_work(tmp_path, capsys, bad):
    rec = arx_plant(tmp_path / "rec.csv")
    assert main(["train", "--data", str(rec), "--out", str(tmp_path / "run"), "--budget", bad]) != 0
    err = capsys.readouterr().err.strip()
    assert "--budget" in err and len(err.splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "run").exists()


def test_the_budget_sets_the_recipes_steps_and_an_override_wins(tmp_path):
    rec = arx_plant(tmp_path / "rec.csv", steps=4000)
    windows = 3600 - 50  # the training part (the last 400 steps validate), windows of 51 steps
    expected = plan_steps(1, windows, 64).steps
    gpt = ["model.arch=gpt"]  # the transformer: windows of 50 steps
    assert training_config(None, None, str(rec), overrides=gpt, budget=1).train.steps == expected
    assert training_config(None, None, str(rec), overrides=["train.steps=7"], budget=1).train.steps == 7
    with pytest.raises(MopError, match="--data"):
        training_config(None, budget=1)


def test_the_budget_buys_the_windows_the_overrides_name(tmp_path):
    """train.horizon / batch_size named on the command line are the windows trained, so the plan is made on
    them: 200-step windows cost four nominal steps each (budget.plan_steps). 2 minutes on the 1600 windows
    of a 2000-step record: 1500 steps of 16 x 200, where the preset's 64 x 50 would plan 1915 (the record's
    70 passes)."""
    rec = arx_plant(tmp_path / "rec.csv", steps=2000)
    over = ["train.horizon=200", "model.context=200", "train.batch_size=16"]
    planned = training_config(None, None, str(rec), overrides=over, budget=2).train
    assert (planned.horizon, planned.batch_size) == (200, 16)
    assert planned.steps == plan_steps(2, 1800 - 200, 16, 200).steps == 1500
    assert plan_steps(2, 1800 - 50, 64).steps == 1915  # what the preset's windows would have planned


@pytest.mark.parametrize("minutes, width", [(5, 32), (8.8, 32), (8.9, 64), (30, 64)])
def test_where_the_record_limits_the_steps_the_budgets_rest_buys_width(minutes, width):
    """The cascaded tanks' 721 training windows of 200 steps: 70 passes are 3155 steps of 16 at 80 ms
    nominal (252 s); at 2.1 times that cost (WIDTH_COST) a width of 64 needs 530 s (8.83 min), so 5
    minutes keep 32 and 8.9 or more buy 64, the widest measured. A budget that limits the steps buys none."""
    plan = plan_steps(minutes, 721, 16, 200)
    assert (plan.steps, plan.limited_by) == (math.ceil(70 * 721 / 16), "record") == (3155, "record")
    assert plan.width(32) == width
    assert plan.width(48) == 48  # a width the costs were not measured at stays
    assert plan_steps(minutes, 10**6, 16, 200).width(32) == 32  # the budget limits the steps
    wider = "the budget's rest widens the network to"
    assert (f"{wider} {width}" in plan.line(base_width=32)) == (width > 32)


def test_a_short_records_run_is_as_wide_as_its_budget_buys_and_an_override_wins(tmp_path):
    """The default network (the deep LRU) on a 700-step record: its 70 passes leave 30 minutes room for a
    width of 64, 1 minute none; model.width=16 named stays 16, and train.steps named (not the plan's steps)
    keeps the body's 32."""
    rec = arx_plant(tmp_path / "rec.csv")
    assert training_config(None, None, str(rec), budget=30).model.width == 64
    assert training_config(None, None, str(rec), budget=1).model.width == 32
    assert training_config(None, None, str(rec), overrides=["model.width=16"], budget=30).model.width == 16
    assert training_config(None, None, str(rec), overrides=["train.steps=50"], budget=30).model.width == 32


def test_a_simulation_that_turns_non_finite_scores_inf_not_its_finite_steps(tmp_path):
    _, data = read_trajectories(arx_plant(tmp_path / "rec.csv", steps=200))
    arx = fit("arx", data)
    assert simulation_rmse(arx, data, 50) < 1
    unstable = dataclasses.replace(arx, model=dataclasses.replace(arx.model, A=3 * arx.model.A))
    sims = simulate_all(unstable, data, 50)[0]
    assert np.isfinite(sims[:20]).all() and not np.isfinite(sims).all()  # finite at first, then it blows up
    assert simulation_rmse(unstable, data, 50) == math.inf


def test_a_network_that_cannot_beat_the_linear_models_ends_as_the_better_one_exactly(tmp_path, capsys):
    """A linear ARX plant and a network ruined on purpose (learning rate 3, 40 steps) whose correction cannot
    be scaled (a Gaussian read-out): the run keeps the linear model that simulates the held-out tail best,
    and predicts exactly what `mop fit KIND` fitted on the same record predicts."""
    rec = arx_plant(tmp_path / "rec.csv")
    run = tmp_path / "run"
    argv = ["train", "--data", str(rec), "--out", str(run), "--no-progress", "train.steps=40", "train.lr=3"]
    argv += ["model.readout=gaussian", "data.feature_input=none"]  # the linear models alone compete
    assert main(argv) == 0
    printed = capsys.readouterr().out
    chosen = json.loads((run / SELECTION_FILE).read_text())
    linear = {k: v["score"] for k, v in chosen["linear_models"].items()}
    kind = min(linear, key=linear.get)
    assert chosen["kept"] == kind and linear[kind] <= chosen["network_rmse"]
    assert set(linear) == {"arx", "n4sid"}
    assert f"keeps the fitted {kind.upper()}" in printed
    assert main(["fit", kind, str(rec), "--out", str(tmp_path / kind)]) == 0
    fitted = load_fitted(tmp_path / kind)
    _, data = read_trajectories(rec)
    from_run = simulate_all(mop.load(run), data, 50)[0]
    np.testing.assert_array_equal(from_run, simulate_all(fitted, data, 50)[0])


def test_a_network_that_beats_the_arx_is_kept(tmp_path, capsys):
    """A plant with a cubic nonlinearity that no ARX can follow: a short run already beats the ARX on the
    held-out tail, and the run predicts with the network."""
    rng = np.random.default_rng(1)
    steps = 1500
    u = rng.normal(size=steps)
    y = np.zeros(steps)
    for t in range(1, steps):
        y[t] = 0.6 * y[t - 1] + 0.8 * np.tanh(3 * u[t - 1]) ** 3
    rec = tmp_path / "rec.csv"
    rec.write_text("y0,u0\n" + "\n".join(f"{a:.8f},{b:.8f}" for a, b in zip(y, u, strict=True)) + "\n")
    run = tmp_path / "run"
    assert main(["train", "--data", str(rec), "--out", str(run), "--no-progress", "train.steps=300"]) == 0
    chosen = json.loads((run / SELECTION_FILE).read_text())
    best_linear = min(v["score"] for v in chosen["linear_models"].values())
    assert chosen["kept"] == "network" and chosen["network_rmse"] < best_linear
    assert not (run / "fitted.json").exists()
    assert hasattr(mop.load(run).predictor_, "model")  # the network, not a fitted model


def test_the_kept_gain_is_the_best_held_out_simulation_and_is_what_the_run_predicts(
    tmp_path, capsys, monkeypatch
):
    """The same ruined network with the mean read-out, without the linear models: its readings and
    correction's gains are scored, the best is kept, the scaled weights are on disk, so loading the run
    simulates the held-out stretches at the recorded RMSE; asking again changes nothing."""
    monkeypatch.setattr(selection, "LINEAR", ())  # the network's readings and gains alone
    rec = arx_plant(tmp_path / "rec.csv")
    run = tmp_path / "run"
    argv = ["train", "--data", str(rec), "--out", str(run), "--no-progress", "train.steps=40", "train.lr=3"]
    assert main([*argv, "model.arch=gpt"]) == 0  # the transformer: its correction has gains
    chosen = json.loads((run / SELECTION_FILE).read_text())
    assert chosen["linear_models"] == {} and chosen["gains"] == list(GAINS)  # trained one step ahead
    reading = load_config(run).model.forecast_mode
    by_gain = [s["score"] for s in chosen["network"][reading]]
    scores = [s["score"] for by in chosen["network"].values() for s in by]
    assert chosen["network_rmse"] > 2 * min(scores)  # the ruined correction at gain 1 is far off
    assert chosen["kept"] == "network"
    kept = chosen["network"][chosen["reading"]][chosen["gains"].index(chosen["gain"])]
    assert kept["score"] == min(scores) and by_gain[-1] == chosen["network_rmse"]
    config = load_config(run)
    record = recorded_data(config.data)
    n = selection.init_window(record)
    stretches = held_out_stretches(record, n)
    assert stretches_rmse(mop.load(run), stretches) == pytest.approx(kept["held_out"], rel=1e-6)
    weights = (run / "model.safetensors").read_bytes()
    assert select_against_linear(run, config, recorded_data(config.data)) == chosen
    assert (run / "model.safetensors").read_bytes() == weights


def test_an_interrupted_records_run_resumed_equals_an_uninterrupted_one(tmp_path, monkeypatch, capsys):
    """`mop train --data` with the records recipe, stopped by Ctrl-C at step 7 and run again with the same
    command, ends with the same weights and the same held-out choice as the run never stopped."""
    from mop.checkpoint import load_tensors
    from tests.reference import sigint_during_step

    rec = arx_plant(tmp_path / "rec.csv", steps=700)
    argv = ["train", "--data", str(rec), "--no-progress", "train.steps=20", "train.checkpoint_every=5"]
    assert main([*argv, "--out", str(tmp_path / "a")]) == 0
    restore = sigint_during_step(monkeypatch, 7)
    assert main([*argv, "--out", str(tmp_path / "b")]) != 0
    restore()
    assert not (tmp_path / "b" / SELECTION_FILE).exists()
    assert main([*argv, "--out", str(tmp_path / "b")]) == 0
    assert "resuming at step" in capsys.readouterr().out
    wa, wb = (load_tensors(tmp_path / run / "model.safetensors")[0] for run in ("a", "b"))
    assert wa.keys() == wb.keys() and all(np.array_equal(wa[k].numpy(), wb[k].numpy()) for k in wa)
    sa, sb = (json.loads((tmp_path / run / SELECTION_FILE).read_text()) for run in ("a", "b"))
    assert sa == sb
