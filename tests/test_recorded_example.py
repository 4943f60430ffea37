"""examples/recorded_data.py on its smoke budget: recordings of systems mop does not ship -> `mop train
--data` -> `mop predict --steps 10` (the run, rls, n4sid-kf, last) -> the held-out table, in sensor units."""

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

import mop
from mop.systems.base import Trajectories
from tests.reference import load_example, run_example_smoke

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "recorded_data.py"
NAMES = ["MOP", "rls", "n4sid-kf", "last"]


@pytest.fixture(scope="module")
def example():
    return load_example(EXAMPLE, "recorded_data_example")


@pytest.fixture(scope="module")
def smoke(example, tmp_path_factory):
    out = tmp_path_factory.mktemp("recorded")
    return out, run_example_smoke(example, out)


def test_table_has_every_horizon_and_predictor(smoke):
    out, rows = smoke
    with open(out / "heldout_errors.csv", newline="") as f:
        table = list(csv.DictReader(f))
    assert [int(r["k"]) for r in table] == list(range(1, 11))
    for r in table:
        assert all(math.isfinite(float(r[n])) and float(r[n]) > 0 for n in NAMES), r
    assert [r["k"] for r in rows] == list(range(1, 11))
    md = (out / "heldout_errors.md").read_text().splitlines()
    assert md[0] == "| k | MOP | rls | n4sid-kf | last |" and len(md) == 12


def test_recordings_vary_in_length_and_train_alone(example, smoke):
    out, _ = smoke
    lengths = [len(y) for y in example.read_csv(out / "train.csv").values()]
    assert min(lengths) >= 40 and max(lengths) <= 80 and len(set(lengths)) > 5
    config = json.loads((out / "run" / "config.json").read_text())
    assert config["data"]["path"] == str(out / "train.csv")  # trained on the file, not a simulated family


def test_run_predicts_in_the_sensors_units(example, smoke):
    """The run's normalisation was fitted in sensor units (std ~ tens); mop.load's one-step predictions equal
    the k = 1 column `mop predict` wrote, and beat the training mean (normalised-unit outputs could not)."""
    out, rows = smoke
    config = json.loads((out / "run" / "config.json").read_text())
    y_mean, y_std = np.array(config["data"]["y_mean"]), np.array(config["data"]["y_std"])
    assert y_std.min() > 10  # 100 x the pendulum's outputs
    heldout = example.read_csv(out / "heldout.csv")
    written = example.read_csv(out / "forecasts" / "MOP.csv", steps=True)
    predictor = mop.load(out / "run")
    mop_err, mean_err = [], []
    for name, y in heldout.items():
        yhat = predictor.predict(Trajectories(y=torch.tensor(y[None]))).numpy()[0]  # (T+1, 2)
        np.testing.assert_allclose(written[name][:, 0], yhat, rtol=1e-6, atol=1e-6 * np.abs(y).max())
        t = np.arange(example.FIRST_ORIGIN, len(y) - example.STEPS + 1)
        mop_err.append(np.linalg.norm(y[t] - yhat[t], axis=-1))
        mean_err.append(np.linalg.norm(y[t] - y_mean, axis=-1))
    mop_err, mean_err = np.concatenate(mop_err).mean(), np.concatenate(mean_err).mean()
    assert mop_err == pytest.approx(rows[0]["MOP"], rel=1e-5)
    assert mop_err < 0.6 * mean_err, (mop_err, mean_err)
