"""mop.estimators from Python as a user meets them: ARX / N4SID equal mop.identify's fits and the numbers
`mop fit` + `mop predict` write for the same files; fixed orders against a numpy least-squares fit; shapes
checked at the door in one line; mop.load takes a `mop fit` directory; simulate(p, traj, 0) is --simulate 0;
the learned model trains through `mop train --data`'s path; examples/compare_estimators.py runs."""

from pathlib import Path

import numpy as np
import pytest
import torch

import mop
from mop.cli import main
from mop.errors import MopError
from mop.estimators import ARX, N4SID, Learned, as_records
from mop.identify import fit
from mop.identify import load as load_fitted
from mop.io import read_trajectories
from mop.predictors import simulate
from mop.recipe.finetune import within_budget
from mop.recipe.layers import training_config
from mop.recipe.plan import RECORDS_BODY
from mop.record import Record, read_records, write_records
from mop.runs import load_config
from mop.systems.base import Trajectories
from tests.reference import load_example

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "compare_estimators.py"
TINY = dict(model__num_layers=1, model__width=16, model__num_heads=2, model__context=8,
            train__horizon=8, train__batch_size=8, train__steps=3, train__log_every=1)  # fmt: skip


def plant(steps, seed, name=""):
    """A seeded second-order plant with an input and equation noise: one Record."""
    rng = np.random.default_rng(seed)
    u, y = rng.normal(size=(steps, 1)), np.zeros((steps, 1))
    for t in range(2, steps):
        y[t] = 1.5 * y[t - 1] - 0.7 * y[t - 2] + 0.5 * u[t - 1] + 0.2 + 0.05 * rng.normal()
    return Record(y=y, u=u, name=name)


@pytest.mark.parametrize("kind, Estimator", [("arx", ARX), ("n4sid", N4SID)])
def test_estimator_equals_identify_fit_on_the_same_data(kind, Estimator):
    records = [plant(200, 0, "a"), plant(150, 1, "b")]
    ours = Estimator(max_order=4).fit(records).predictor_
    ref = fit(kind, [r.pair for r in records], max_order=4, source="a")
    assert ours.orders == ref.orders
    for name in ("A", "B", "C", "K", "b", "d", "x0"):
        np.testing.assert_array_equal(getattr(ours.model, name), getattr(ref.model, name))


def test_arx_of_given_orders_is_the_least_squares_fit():
    rec = plant(300, 2)
    y, u = rec.y, rec.u
    rows = [np.concatenate([y[t - 1], y[t - 2], y[t - 3], u[t - 1], [1.0]]) for t in range(3, len(y))]
    Phi, Y = np.array(rows), y[3:]
    theta = np.linalg.solve(Phi.T @ Phi, Phi.T @ Y)
    est = ARX(na=3, nb=1).fit(rec)
    assert est.chosen_orders == {"p": 3, "q": 1}
    np.testing.assert_allclose(est.predictor_.model.C, theta[:-1].T, atol=1e-10)
    yhat = est.predict(rec)  # (T, m), through float32 batches as `mop predict`
    assert yhat.shape == (300, 1)
    np.testing.assert_allclose(yhat[3:], Phi @ theta, rtol=1e-5, atol=1e-5)
    assert est.forecast(rec, 4).shape == (300, 4, 1)
    np.testing.assert_array_equal(est.forecast(rec, 4)[:, 0], yhat)


@pytest.mark.parametrize("kind, Estimator", [("arx", ARX), ("n4sid", N4SID)])
@pytest.mark.parametrize("init", [0, 40])
def test_simulate_equals_mop_fit_and_mop_predict_simulate_on_the_same_files(
    kind, Estimator, init, tmp_path, capsys
):
    est_csv = write_records([plant(240, 3, "est")], tmp_path / "est.csv")
    val_csv = write_records([plant(120, 4, "v1"), plant(120, 5, "v2")], tmp_path / "val.csv")
    assert main(["fit", kind, str(est_csv), "--out", str(tmp_path / "model"), "--max-order", "4"]) == 0
    out = tmp_path / "sim.npz"
    argv = ["predict", str(tmp_path / "model"), str(val_csv), "--simulate", str(init), "--out", str(out)]
    assert main(argv) == 0
    capsys.readouterr()
    cli = np.load(out)["ysim"]  # (B, T+1-C, m), C = max(init, 1)
    model = Estimator(max_order=4).fit(mop.read_records(est_csv))
    ours = model.simulate(str(val_csv), init=init)
    start = max(init, 1)
    for b, sim in enumerate(ours):
        assert np.isnan(sim[:start]).all()
        np.testing.assert_array_equal(sim[start:], cli[b])
    # mop.load takes the `mop fit` directory, and simulate(p, traj, 0) is --simulate 0
    p = mop.load(tmp_path / "model")
    val = read_records(val_csv)
    traj = Trajectories(
        y=torch.tensor(np.stack([r.y for r in val]), dtype=torch.float32),
        u=torch.tensor(np.stack([r.u for r in val]), dtype=torch.float32),
    )
    np.testing.assert_array_equal(simulate(p, traj, start).numpy(), cli)
    if init == 0:
        np.testing.assert_array_equal(simulate(p, traj, 0).numpy(), cli)


def test_records_round_trip_through_the_csv_bit_for_bit(tmp_path):
    rec = plant(50, 6, "r")
    y = rec.y.copy()
    y[[3, 7]] = np.nan
    back = read_records(write_records([Record(y=y, u=rec.u, name="r")], tmp_path / "r.csv"))[0]
    np.testing.assert_array_equal(back.y, y)
    np.testing.assert_array_equal(back.u, rec.u)


def one_line(excinfo) -> str:
    message = str(excinfo.value)
    assert "\n" not in message
    return message


def test_shapes_are_checked_at_the_door_in_one_line():
    rec = plant(100, 7)
    with pytest.raises(MopError) as e:  # a 2-D array where the batch (B, T+1, m) was needed
        Trajectories(y=torch.zeros(100, 1))
    assert "(B, T+1, m)" in one_line(e)
    with pytest.raises(MopError) as e:
        Trajectories(y=torch.zeros(1, 100, 1), u=torch.zeros(100, 1))
    assert "u is (B, T+1, k)" in one_line(e)
    with pytest.raises(MopError) as e:
        ARX().fit(np.zeros((2, 3, 4, 5)))
    assert "shape (2, 3, 4, 5)" in one_line(e)
    with pytest.raises(MopError) as e:
        ARX().fit((rec.y, rec.u[:50]))
    assert "u has 50 steps and y 100" in one_line(e)
    with pytest.raises(MopError) as e:
        ARX().predict(rec)
    assert "not fitted yet" in one_line(e)
    model = ARX(2, 1).fit(rec)
    with pytest.raises(MopError) as e:
        model.predict(Record(y=np.zeros((100, 2)), u=rec.u))
    assert "fitted on 1 output(s) and 1 input(s)" in one_line(e)
    with pytest.raises(MopError) as e:
        model.simulate(rec, init=100)
    assert "init must be an integer in [0, 99]" in one_line(e)
    with pytest.raises(MopError) as e:
        ARX(na=2)
    assert "both orders" in one_line(e)
    with pytest.raises(MopError) as e:
        ARX(2, 0).fit(rec)
    assert "do not fit a record with 1 input(s); give orders like {'p': 10, 'q': 10}" in one_line(e)
    with pytest.raises(MopError) as e:
        as_records(42)
    assert "got int" in one_line(e)
    # a batch (B, T, m) is B records; (T,) arrays are one channel
    assert len(as_records((np.zeros((3, 20, 1)), np.zeros((3, 20, 2))))[0]) == 3
    (one,), single = as_records((np.zeros(20), np.zeros(20)))
    assert single and one.y.shape == (20, 1) and one.u.shape == (20, 1)


def test_learned_trains_through_mop_train_data_and_predicts_as_mop_load(tmp_path):
    rec = plant(160, 8, "r")
    model = Learned(out_dir=tmp_path, **TINY).fit(rec)
    config = load_config(model.run_dir_)
    assert config.train.steps == 3 and config.model.width == 16
    assert config.data.path == "r"  # where the record came from: its name (no file of it is written)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]
    assert (
        config.model.arch == RECORDS_BODY["model.arch"]
    )  # the records recipe's, as `mop train --data` gives
    yhat = model.predict(rec)
    assert yhat.shape == (160, 1) and np.isfinite(yhat).all()
    traj = Trajectories(
        y=torch.tensor(rec.y[None], dtype=torch.float32), u=torch.tensor(rec.u[None], dtype=torch.float32)
    )
    np.testing.assert_array_equal(yhat, mop.load(model.run_dir_).predict(traj)[0].double().numpy())
    sim = model.simulate(rec, init=20)
    assert np.isnan(sim[:20]).all() and np.isfinite(sim[20:]).all()
    with pytest.raises(MopError) as e:
        Learned(budget_minutes=0)
    assert "budget_minutes" in one_line(e)


def test_a_budget_cuts_the_steps_and_never_raises_them(tmp_path):
    path = write_records([plant(160, 9, "r")], tmp_path / "r.csv")
    overrides = [f"{k.replace('__', '.')}={v}" for k, v in TINY.items() if k != "train__steps"]
    config = training_config(None, None, str(path), None, overrides)
    assert config.train.steps > 1
    assert within_budget(config, 1e-9).train.steps == 1  # no time: one step
    assert within_budget(config, 1e6).train.steps == config.train.steps  # all the time: the recipe's


def test_compare_estimators_example_runs():
    module = load_example(EXAMPLE, "compare_estimators_example")
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        rmse = module.main(["--tiny"])
    finally:
        torch.set_num_threads(threads)
    assert set(rmse) == {"ARX", "N4SID", "Learned"} and all(np.isfinite(v) for v in rmse.values())
    assert rmse["ARX"] < 1.0  # the tanh output's scale: a fitted linear model is not off the chart


@pytest.mark.parametrize("kind, Estimator", [("arx", ARX), ("n4sid", N4SID)])
def test_mop_fit_saves_what_the_estimator_fits_on_the_file(tmp_path, kind, Estimator, capsys):
    """`mop fit KIND FILE` is the estimator fitted on FILE (the file names the estimation record), which is
    mop.identify's fit of the file's (y, u) pairs."""
    path = write_records([plant(200, 0, "a"), plant(150, 1, "b")], tmp_path / "est.csv")
    assert main(["fit", kind, str(path), "--out", str(tmp_path / "m"), "--max-order", "4"]) == 0
    saved = load_fitted(tmp_path / "m").to_json()
    ours = Estimator(max_order=4).fit(str(path)).predictor_.to_json()
    ref = fit(kind, read_trajectories(path)[1], max_order=4, source=str(path)).to_json()
    assert saved == ours == ref and saved["estimation"] == "est.csv"
