"""examples/tank_records.py on its smoke budget: one cascaded-tanks plant, est.csv and val.csv -> `mop train
--data est.csv` (the records recipe), `mop fit arx|n4sid est.csv` -> `mop predict` one-step and simulated."""

import csv
from pathlib import Path

import numpy as np
import pytest
import torch

from tests.reference import load_example

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "tank_records.py"


@pytest.fixture(scope="module")
def smoke(tmp_path_factory):
    module = load_example(EXAMPLE, "tank_records_example")
    out = tmp_path_factory.mktemp("tanks")
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        rows = module.main(["--out", str(out), "--budget", "smoke", "--seeds", "2"])
    finally:
        torch.set_num_threads(threads)
    return out, rows


def test_table_and_records(smoke):
    """Two records of 300 samples with other inputs; every predictor has finite
    figures; the fitted ARX predicts one step ahead better than the last value (the tanks follow the pump)."""
    out, rows = smoke
    est, val = (
        np.loadtxt(out / f"{n}.csv", delimiter=",", skiprows=1, usecols=(2, 3)) for n in ("est", "val")
    )
    assert est.shape == val.shape == (300, 2) and not np.allclose(est[:, 1], val[:, 1])
    with open(out / "validation.csv", newline="") as f:
        table = list(csv.DictReader(f))
    names = [r["predictor"] for r in table]
    assert names.count(load_example(EXAMPLE, "tank_records_example").MOP) == 2 and "arx (fitted)" in names
    assert all(np.isfinite(float(r[k])) for r in table for k in ("one_step", "simulation"))
    arx, last = rows["arx (fitted)"][0], rows["last"][0]
    assert arx["one_step"] < last["one_step"]
    fitted = (out / "fit-arx.log").read_text()
    assert "chosen p=" in fitted
