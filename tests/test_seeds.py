"""`mop reproduce --seeds K`: same test systems, K training seeds, mean/range/CI per ratio; the report's
distance to the best predictor; the summary table of `reproduce all` (mop.experiments.seeds)."""

import json

import numpy as np
import pytest

from mop import cli
from mop.experiments.evaluating import distance_to_best
from mop.experiments.seeds import lead_table, seed_summary, seeds_table
from mop.metrics import mse_ratio_ci


def _eval(ratio_ref, ratio_best):
    return {
        "conditions": {
            "test": {
                "ratios_to_reference": {
                    "reference": "kalman",
                    "ratios": {"mop": {"[20,51)": {"ratio": ratio_ref, "low": 0.9, "high": 1.2}}},
                },
                "to_best": {"predictor": "pf", "ratio": ratio_best, "low": 0.8, "high": 1.4},
            }
        }
    }


def test_seed_summary_mean_range_and_each_ci():
    s = seed_summary({0: _eval(1.0, 1.1), 1: _eval(1.2, 1.3), 2: _eval(1.1, 0.9)})
    ref, best = s["test"]["reference"], s["test"]["best"]
    assert ref["mean"] == pytest.approx(1.1) and (ref["min"], ref["max"]) == (1.0, 1.2)
    assert best["predictor"] == "pf" and (best["min"], best["max"]) == (0.9, 1.3)
    assert [v["seed"] for v in best["per_seed"]] == [0, 1, 2]
    table = seeds_table("x", s)
    assert "MOP / pf | 1.100 [0.900, 1.300]" in table and "1.300 [0.800, 1.400]" in table
    assert table.count("| test |") == 2  # MOP / pf and MOP / kalman
    # where the best predictor is the reference, the condition has one row
    same = _eval(1.0, 1.0)
    same["conditions"]["test"]["to_best"]["predictor"] = "kalman"
    assert seeds_table("x", seed_summary({0: same})).count("| test |") == 1
    lead = lead_table(
        [
            {"experiment": "x", "best": best, "authors": "0.07"},
            {"experiment": "y", "best": None, "authors": ""},
        ]
    )
    assert "| x | pf | 1.100 [0.900, 1.300]" in lead and lead.rstrip().endswith("| y | - | - | - | - |")


def test_distance_to_best_is_the_bootstrap_ratio_over_the_late_window():
    rng = np.random.default_rng(0)
    errors = {"mop": rng.random((40, 51)) + 0.5, "pf": rng.random((40, 51)) + 0.4}
    d = distance_to_best(errors, "pf", seed=3)
    assert (d["ratio"], d["low"], d["high"]) == mse_ratio_ci(errors["mop"], errors["pf"], 20, 51, seed=3)
    assert d["predictor"] == "pf" and d["window"] == [20, 51]
    assert distance_to_best(errors, "kalman", seed=0) is None


def test_reproduce_seeds_trains_each_seed_on_the_same_test_systems(tmp_path, tiny_smoke, capsys):
    out = tmp_path / "lin"
    argv = ["reproduce", "linear", "--preset", "smoke", "--out", str(out), "--quiet", "--seeds", "2"]
    assert cli.main(argv) == 0
    evals = [json.loads((out / f"seed-{s}" / "eval.json").read_text()) for s in (0, 1)]
    assert [e["train_seed"] for e in evals] == [0, 1] and evals[0]["seed"] == evals[1]["seed"] == 0
    kf = [e["predictors"]["kalman"]["error"] for e in evals]
    assert kf[0] == kf[1]  # the same test systems
    assert evals[0]["predictors"]["mop"]["error"] != evals[1]["predictors"]["mop"]["error"]  # two models
    assert len(set(evals[0]["runs"].values()) | set(evals[1]["runs"].values())) == 2
    summary = json.loads((out / "seeds.json").read_text())
    per_seed = [v["ratio"] for v in summary["test"]["best"]["per_seed"]]
    assert per_seed == [e["to_best"]["ratio"] for e in evals]
    assert summary["test"]["best"]["predictor"] == "kalman"
    assert "across training seeds" in (out / "seeds.md").read_text()
    report = (out / "seed-0" / "report.md").read_text()
    assert "## MOP against the yardstick" in report and "1.025" in report  # beside the authors'


def test_reproduce_seeds_must_be_positive(capsys):
    assert cli.main(["reproduce", "linear", "--seeds", "0"]) == 2
    assert "--seeds must be at least 1" in capsys.readouterr().err
