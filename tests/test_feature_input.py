"""A network reading its least-squares feature's free run (data.feature_input = "free-run",
mop.models.feature_input, mop.recipe.feature_input): the channel is the feature's one-step prediction, then
its free run, and never reads an output at or after the step it stands for; a run trains on it, holds the
feature, and simulates a record as the feature's run plus its network's residual."""

import dataclasses

import numpy as np
import pytest
import torch

import mop
import mop.recipe.records as records_recipe
from mop.checkpoint import save_model
from mop.config import DataConfig
from mop.errors import MopError
from mop.identify.narx_model import KIND, fit_cubic_narx
from mop.models.feature_input import INIT_KEY, FeatureInputPredictor, feature_channel
from mop.recipe.feature_input import run_feature
from mop.recipe.fit import fine_tune_record, fit_record
from mop.recipe.records import fitted_feature
from mop.recipe.selection import check_scores
from mop.record import Record
from mop.records import simulate_all
from mop.runs import load_config, load_predictor
from mop.train.records import TrainingRecords

from .test_narx_model import MOMENTS, cubic_record, traj

pytestmark = pytest.mark.usefixtures("one_thread")


def noisy_record(steps: int = 1500) -> Record:
    record = cubic_record(steps, seed=4)
    noise = 0.01 * np.random.default_rng(5).normal(size=record.y.shape)
    return Record(y=record.y + noise, u=record.u, name="cubic")


def test_the_channel_is_the_one_step_prediction_then_the_free_run_and_reads_no_later_output():
    """s_t for t < c is the feature's one-step prediction of the whole record's (from y_<t), for t >= c its
    free run from y_<c (mop.predictors.simulate); changing y_c.. changes nothing, and changing y_t (t < c)
    changes no s_<=t."""
    record = cubic_record(300)
    feature = fit_cubic_narx([record], 2, 2, 1, moments=MOMENTS)
    t, c = traj(record), 40
    s = feature_channel(feature, t, c)
    np.testing.assert_array_equal(s[:, :c].numpy(), feature.predict(t)[:, :c].numpy())
    np.testing.assert_array_equal(s[:, c:].numpy(), feature.simulate(t, c).numpy())
    later = t.y.clone()
    later[:, c:] += 5.0
    np.testing.assert_array_equal(
        feature_channel(feature, dataclasses.replace(t, y=later), c).numpy(), s.numpy()
    )
    earlier = t.y.clone()
    earlier[:, 20] += 5.0
    moved = feature_channel(feature, dataclasses.replace(t, y=earlier), c)
    np.testing.assert_array_equal(moved[:, :21].numpy(), s[:, :21].numpy())
    assert not torch.equal(moved[:, 21:], s[:, 21:])


def run_files(run_dir, out):
    """A copy of the run directory's files (not its folders: RUN/feature, tb) in a new folder `out`."""
    out.mkdir()
    for f in run_dir.iterdir():
        if f.is_file():
            (out / f.name).write_bytes(f.read_bytes())
    return out


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A deep LRU of the records recipe, 30 steps, reading its cubic feature's run."""
    out = tmp_path_factory.mktemp("feature-input") / "run"
    records = TrainingRecords((noisy_record(),), source="cubic")
    return fit_record(
        out, records, overrides=["data.feature_input=free-run", "train.steps=30"], progress=False
    )


def test_the_run_holds_the_feature_fitted_on_its_training_part_and_the_check_scores_it(run):
    """RUN/feature is fit_cubic_narx of the orders the recipe chose on the training part (bit for bit), with
    the window its records were read from; the network reads k + m inputs; the held-out check scores the
    feature beside the network and the fitted linear models."""
    loaded = load_predictor(run.run_dir)
    assert isinstance(loaded, FeatureInputPredictor)
    feature = loaded.feature
    split = TrainingRecords((noisy_record(),)).split(run.config.data)
    train = [(a[:, :1], a[:, 1:]) for a in split.train_parts]
    refit = fit_cubic_narx(train, **feature.orders, moments=split.fit())
    np.testing.assert_array_equal(feature.theta, refit.theta)
    assert feature.orders["c"] >= 1 and feature.info[INIT_KEY] == 50
    assert loaded.model.cfg.input_dim == 1 + 1 + 1 + 1  # y, u, the feature's run, the observation mask
    assert set(run.selection["linear_models"]) == {"arx", "n4sid", KIND}


def test_a_silent_network_simulates_the_features_run_plus_the_residuals_training_mean(run, tmp_path):
    """With its read-out zeroed the network predicts its residual's training mean (data.y_mean, in the
    normalisation of the records it trained on), so the run simulates the record as the feature's free run
    plus that mean: the composition and both normalisations in closed form."""
    record = noisy_record()
    silent = run_files(run.run_dir, tmp_path / "silent")
    (silent / "feature").mkdir()
    (silent / "feature" / "fitted.json").write_bytes((run.run_dir / "feature" / "fitted.json").read_bytes())
    (silent / "fitted.json").unlink(missing_ok=True)  # the network, whatever the check kept
    loaded = load_predictor(silent)
    with torch.no_grad():
        loaded.model.read_out.weight.zero_()
        loaded.model.read_out.bias.zero_()
    save_model(silent / "model.safetensors", loaded.model)
    network = mop.load(silent)
    sim = network.simulate(record, init=50)
    expected = loaded.feature.simulate(traj(record), 50)[0].numpy() + load_config(run.run_dir).data.y_mean[0]
    np.testing.assert_allclose(sim[50:], expected, rtol=1e-6, atol=1e-6 * np.abs(record.y).max())
    assert np.isnan(sim[:50]).all()


def test_its_simulation_reads_no_output_after_the_window_and_one_step_reads_only_the_past(run):
    """simulate(., c) is unchanged by y_c..; predict's y_t reads y_<t only (the channel too)."""
    record = noisy_record()
    loaded = load_predictor(run.run_dir)
    t = traj(record)
    later = t.y.clone()
    later[:, 60:] += 3.0
    moved = dataclasses.replace(t, y=later)
    np.testing.assert_array_equal(loaded.simulate(t, 60).numpy(), loaded.simulate(moved, 60).numpy())
    np.testing.assert_array_equal(loaded.predict(t)[:, :61].numpy(), loaded.predict(moved)[:, :61].numpy())
    assert not torch.equal(loaded.predict(t)[:, 61:], loaded.predict(moved)[:, 61:])


def test_a_run_without_its_feature_is_named_in_one_line(run, tmp_path):
    """A run stopped before it wrote RUN/feature (a crash mid-training) is refused, saying what to do."""
    bare = run_files(run.run_dir, tmp_path / "bare")
    with pytest.raises(MopError, match="holds no feature/.*train the run again"):
        load_predictor(bare)


def test_mop_load_reads_the_records_own_channels_and_refuses_others(run):
    """mop.load(RUN) simulates a record of one output and one input (the network reads three), equal to
    simulate_all on the same predictor; a record of two inputs gets one line naming the columns."""
    record = noisy_record()
    loaded = mop.load(run.run_dir)
    assert loaded.shape_ == (1, 1)
    sim = loaded.simulate(record, init=50)
    np.testing.assert_array_equal(sim[50:], simulate_all(loaded.predictor_, [record.pair], 50)[0])
    wide = Record(y=record.y, u=np.concatenate([record.u, record.u], 1))
    with pytest.raises(MopError, match=r"1 input\(s\); these data have 1 and 2"):
        loaded.simulate(wide, init=50)


def test_a_record_with_gaps_or_a_bad_choice_is_refused_before_training(tmp_path):
    record = noisy_record(400)
    y = record.y.copy()
    y[100] = np.nan
    gaps = TrainingRecords((Record(y=y, u=record.u),), source="gaps")
    with pytest.raises(MopError, match="complete outputs"):
        fit_record(tmp_path / "a", gaps, overrides=["data.feature_input=free-run"], progress=False)
    assert not (tmp_path / "a").exists()
    with pytest.raises(MopError, match="data.feature_input"):
        fit_record(
            tmp_path / "b", TrainingRecords((record,)), overrides=["data.feature_input=sim"], progress=False
        )


def test_a_fine_tune_keeps_the_weights_and_refits_the_feature_on_its_record(run, tmp_path):
    """`--init RUN` on another record of the plant (a tenth the noise, another input): at lr 1e-30 the
    network's weights and normalisation are the source's, and its feature is refitted on the new record's
    training part with the orders the recipe chooses there (fit_cubic_narx of those orders, bit for bit)."""
    record = cubic_record(1500, seed=9)
    records = TrainingRecords((record,), source="other")
    tuned = fine_tune_record(
        tmp_path / "ft",
        records,
        str(run.run_dir),
        overrides=["train.steps=1", "train.lr=1e-30"],
        progress=False,
    )
    a, b = (load_predictor(r).model.state_dict() for r in (run.run_dir, tuned.run_dir))
    for key in a:
        torch.testing.assert_close(b[key], a[key], rtol=0, atol=1e-12)
    assert load_config(tuned.run_dir).data.y_mean == load_config(run.run_dir).data.y_mean
    feature = load_predictor(tuned.run_dir).feature
    split = records.split(tuned.config.data)
    train = [(x[:, :1], x[:, 1:]) for x in split.train_parts]
    refit = fit_cubic_narx(train, **feature.orders, moments=split.fit())
    np.testing.assert_array_equal(feature.theta, refit.theta)
    assert not np.array_equal(feature.theta, load_predictor(run.run_dir).feature.theta)


def linear_record(steps: int = 1500) -> Record:
    """y_t = 1.2 y_{t-1} - 0.5 y_{t-2} + 0.8 u_{t-1} + noise: a plant with nothing to cube."""
    rng = np.random.default_rng(8)
    u, y = rng.normal(size=steps), np.zeros(steps)
    for t in range(2, steps):
        y[t] = 1.2 * y[t - 1] - 0.5 * y[t - 2] + 0.8 * u[t - 1] + 0.05 * rng.normal()
    return Record(y=y[:, None], u=u[:, None], name="linear")


@pytest.mark.parametrize("plant", ["cubic", "linear"])
def test_the_feature_read_is_the_one_the_check_scores_lower(plant, monkeypatch):
    """A cubic NARX is read only where it scores below the feature without cubes on the check's own
    stretches (mop.recipe.selection.check_scores). On the cubic plant the cubic NARX is kept; on a linear
    plant offered cubes of every output lag (choose_cubes made to propose them), whichever of the two
    scores lower there, each scored here as the check scores it."""
    if plant == "linear":
        monkeypatch.setattr(records_recipe, "choose_cubes", lambda parts, p, q: (p, p, {}))
    rec = noisy_record() if plant == "cubic" else linear_record()
    record = TrainingRecords((rec,)).split(DataConfig(path=plant))
    cubic, linear = fitted_feature(record)[0], fitted_feature(record, cubes=False)[0]
    assert cubic.orders["c"] > 0 and linear.orders["c"] == 0
    scores = [check_scores(f, record)["score"] for f in (cubic, linear)]
    read = run_feature(record)
    expected = (cubic, linear)[int(np.argmin(scores))]
    assert read.orders == expected.orders and np.array_equal(read.theta, expected.theta)
    if plant == "cubic":
        assert read.orders["c"] > 0
