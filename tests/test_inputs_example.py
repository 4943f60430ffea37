"""examples/recordings_with_inputs.py on its smoke budget: `mop simulate linear-inputs` -> `mop train --data`
-> `mop predict` one-step and `--simulate C` (the run, arx, n4sid-kf, last, kalman) -> the held-out table."""

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from mop.predictors import make_predictor, simulate
from mop.systems import FAMILIES
from mop.systems.base import Trajectories
from tests.reference import load_example, run_example_smoke

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "recordings_with_inputs.py"


@pytest.fixture(scope="module")
def example():
    return load_example(EXAMPLE, "recordings_with_inputs_example")


@pytest.fixture(scope="module")
def smoke(example, tmp_path_factory):
    out = tmp_path_factory.mktemp("inputs")
    return out, run_example_smoke(example, out)


def test_table_has_every_predictor_and_the_filters_order(example, smoke):
    """Every predictor has finite errors; on linear systems with inputs the Kalman filter that knows them
    beats ARX, and ARX beats repeating the last output, one-step and in simulation (by wide margins: last
    ignores the inputs)."""
    out, rows = smoke
    with open(out / "heldout_errors.csv", newline="") as f:
        table = {r["predictor"]: r for r in csv.DictReader(f)}
    assert list(table) == list(example.PREDICTORS)
    for r in table.values():
        assert all(math.isfinite(float(r[k])) and float(r[k]) > 0 for k in list(r)[1:]), r
    err = {r["predictor"]: r for r in rows}
    for key in ("one_step", "simulation"):
        assert err["kalman"][key] < err["arx"][key] < 0.8 * err["last"][key], key
    assert (out / "heldout_errors.md").read_text().count("\n") == 2 + len(example.PREDICTORS)


def test_trained_on_the_file_with_its_inputs(example, smoke):
    out, _ = smoke
    config = json.loads((out / "run" / "config.json").read_text())
    assert config["data"]["path"] == str(out / "train.npz")  # trained on the recordings, not a family
    assert config["model"]["input_dim"] == 3 and config["model"]["output_dim"] == 2  # reads [y_t, u_t]


def test_simulation_file_is_the_free_run_of_the_filter(example, smoke):
    """The written simulation of kalman equals mop.predictors.simulate on the same held-out trajectories."""
    out, _ = smoke
    data = np.load(out / "heldout.npz")
    arrays = {k[len("param_") :]: data[k] for k in data.files if k.startswith("param_")}
    params = FAMILIES.get(str(data["family"])).Params.from_arrays(arrays, by="the test", where="heldout.npz")
    traj = Trajectories(
        y=torch.from_numpy(data["y"]).double(),
        u=torch.from_numpy(data["u"]).double(),
        params=params.map(torch.Tensor.double),
        family=str(data["family"]),
    )
    expect = simulate(make_predictor("kalman"), traj, example.CONTEXT).numpy()
    np.testing.assert_allclose(
        np.load(out / "simulation" / "kalman.npz")["ysim"], expect, rtol=1e-4, atol=1e-5
    )
