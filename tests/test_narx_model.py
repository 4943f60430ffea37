"""The records recipe's least-squares feature as a model of its own (mop.identify.narx_model.FittedNARX):
it recovers a cubic NARX exactly, is the fitted ARX where it has no cubes, survives fitted.json, and is a
candidate of the held-out check of a network that reads no feature, which then loads it."""

import json

import numpy as np
import pytest
import torch

import mop
from mop.config import DataConfig
from mop.errors import MopError
from mop.identify import load as load_fitted
from mop.identify.cubic import simulate_narx
from mop.identify.narx_model import KIND, FittedNARX, fit_cubic_narx
from mop.identify.select import fit_orders
from mop.predictors import forecast, simulate
from mop.recipe import selection
from mop.recipe.fit import fit_record
from mop.record import Record
from mop.records import simulate_all
from mop.systems.base import Trajectories
from mop.train.records import TrainingRecords

pytestmark = pytest.mark.usefixtures("one_thread")
MOMENTS = {"y_mean": [2.0], "y_std": [3.0], "u_mean": [1.0], "u_std": [0.5]}
# y_{t+1} = 1.6 y_t - 0.8 y_{t-1} - 0.1 y_t^3 + 0.3 u_t + 0.1 u_{t-1} + 0.05, in the normalised units
THETA = np.array([[1.6], [-0.8], [-0.1], [0.3], [0.1], [0.05]])


def cubic_record(steps: int = 800, seed: int = 0) -> Record:
    """A record of THETA's cubic NARX (p = 2, q = 2, c = 1) in MOMENTS' units, noise-free."""
    rng = np.random.default_rng(seed)
    zu = rng.normal(size=(steps, 1))
    z = np.zeros((steps, 1))
    z[:2] = 0.1 * rng.normal(size=(2, 1))
    z[2:] = simulate_narx(THETA, z, zu, 2, 2, 1, 2)
    return Record(y=2.0 + 3.0 * z, u=1.0 + 0.5 * zu, name="cubic")


def traj(record: Record) -> Trajectories:
    return Trajectories(torch.tensor(record.y[None]), torch.tensor(record.u[None]), None, None, "record")


def test_it_recovers_a_cubic_narx_and_predicts_forecasts_and_simulates_it():
    """Plain least squares (ridge 0) on the plant's own regressors: theta to 1e-6, one step and 4
    steps ahead to 1e-5 of the record, its free run of 795 steps after 5 (a lightly damped plant: the
    coefficients' 1e-7 grow along it) to 1e-4, in outputs of about +-5."""
    record = cubic_record()
    model = fit_cubic_narx([record], 2, 2, 1, moments=MOMENTS, ridge=0.0)
    np.testing.assert_allclose(model.theta, THETA, atol=1e-6)
    t = traj(record)
    np.testing.assert_allclose(simulate(model, t, 5)[0].numpy(), record.y[5:], atol=1e-4)
    np.testing.assert_allclose(model.predict(t)[0, 2:].numpy(), record.y[2:], atol=1e-5)
    ahead = forecast(model, t, 4)[0, 2:-3, 3].numpy()  # y_{t+3} from y_<t
    np.testing.assert_allclose(ahead, record.y[5:], atol=1e-5)


def test_without_cubes_it_simulates_as_the_fitted_arx_of_the_same_orders():
    """c = 0 is an ARX(p, q) with an intercept: with ridge 0 the same least squares as `mop fit arx` with
    those orders (mop.identify.arx, in the record's units), so the same free run (to float32 rounding:
    simulate_all batches in float32), on a noisy record off its class."""
    record = cubic_record(600, seed=1)
    noisy = Record(y=record.y + 0.05 * np.random.default_rng(2).normal(size=record.y.shape), u=record.u)
    narx = fit_cubic_narx([noisy], 3, 2, 0, ridge=0.0)
    arx = fit_orders("arx", [noisy], {"p": 3, "q": 2})
    data = [(noisy.y, noisy.u)]
    np.testing.assert_allclose(simulate_all(narx, data, 10)[0], simulate_all(arx, data, 10)[0], atol=1e-5)


def test_its_coefficients_are_those_a_transformers_feature_starts_from():
    """The default fit is the feature prior of a transformer reading the records recipe's feature
    (mop.train.records.RecordedData.fit_prior, model.rls_prior=fit): the same least squares, ridge and
    normalisation (the training part's moments), so the model is that feature alone (its gain 0)."""
    record = cubic_record(900, seed=6)
    split = TrainingRecords((record,), source="cubic").split(DataConfig(path="cubic"))
    moments = split.fit()
    train = [(a[:, :1], a[:, 1:]) for a in split.train_parts]
    model = fit_cubic_narx(train, 3, 2, 2, moments=moments)
    prior = split.fit_prior(DataConfig(path="cubic", **moments), 3, 2, True, 2)
    np.testing.assert_array_equal(model.theta.reshape(-1), prior)


def test_it_survives_fitted_json_and_a_damaged_file_is_named(tmp_path):
    model = fit_cubic_narx([cubic_record()], 2, 2, 1)
    (tmp_path / "m").mkdir()
    (tmp_path / "m" / "fitted.json").write_text(json.dumps({"format": 1, **model.to_json()}))
    loaded = load_fitted(tmp_path / "m")
    assert isinstance(loaded, FittedNARX) and loaded.orders == {"p": 2, "q": 2, "c": 1}
    t = traj(cubic_record(300, seed=3))
    assert torch.equal(simulate(loaded, t, 5), simulate(model, t, 5))
    broken = {**model.to_json(), "orders": {"p": 3, "q": 2, "c": 1}}  # theta of (2, 2, 1)
    (tmp_path / "m" / "fitted.json").write_text(json.dumps({"format": 1, **broken}))
    with pytest.raises(MopError, match="fitted.json is damaged"):
        load_fitted(tmp_path / "m")
    assert KIND == model.to_json()["kind"]


def test_a_featureless_run_keeps_the_cubic_feature_where_it_simulates_best_and_loads_it(tmp_path):
    """A ruined deep LRU (learning rate 3) on a cubic plant the recipe gives cubed lags: the check scores
    the feature as a candidate of its own, keeps it (below the fitted ARX and N4SID), and the run loads
    it as scored, simulating as fit_cubic_narx of the same orders on the training part does."""
    record = cubic_record(1500, seed=4)
    noisy = Record(y=record.y + 0.01 * np.random.default_rng(5).normal(size=record.y.shape), u=record.u)
    records = TrainingRecords((noisy,), source="cubic")
    run = fit_record(tmp_path / "run", records, overrides=["train.steps=20", "train.lr=3"], progress=False)
    chosen = run.selection
    assert run.config.model.rls_order == 0  # the recipe's deep LRU reads no feature
    scores = {k: s["score"] for k, s in chosen["linear_models"].items()}
    assert chosen["kept"] == KIND and scores[KIND] < min(scores["arx"], scores["n4sid"])
    orders = chosen["linear_orders"][KIND]
    assert orders["c"] >= 1
    loaded = mop.load(run.run_dir).predictor_
    split = TrainingRecords((noisy,)).split(run.config.data)
    train = [(a[:, :1], a[:, 1:]) for a in split.train_parts]
    refit = fit_cubic_narx(train, **orders, moments=split.fit())
    data = [(noisy.y, noisy.u)]
    np.testing.assert_array_equal(simulate_all(loaded, data, 50)[0], simulate_all(refit, data, 50)[0])
    assert "least-squares feature, NARX(p=" in selection.selection_line(chosen)
    # trained further on a record, it is fitted anew there with its orders, as a `mop fit` folder is
    again = mop.load(run.run_dir).fit(record).predictor_
    np.testing.assert_array_equal(again.theta, fit_cubic_narx([record], **orders).theta)
