"""`mop bench features`: the variants it times are the configs the small preset trains (auto's, the same with
one Gaussian, none), each with the steps the budget gives its features; one-line errors."""

import json
from pathlib import Path

import pytest

from mop.cli import main
from mop.experiments.presets import PRESETS
from mop.train.auto import STEP_COST, steps_for

DEAD_TIME = Path(__file__).resolve().parents[1] / "examples" / "dead_time.py"


def test_bench_features_times_the_configs_the_small_preset_trains(capsys):
    argv = ["bench", "features", "--family", "dead-time", "--plugin", str(DEAD_TIME)]
    assert main([*argv, "--rounds", "1", "--warmup", "0", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    rows = {row["variant"]: row for row in r["variants"]}
    assert list(rows) == ["plain", "one Gaussian", "auto"]
    assert rows["plain"]["features"] == "none" and rows["plain"]["steps"] == PRESETS["small"].train.steps
    assert rows["auto"]["features"].endswith("components")
    assert rows["one Gaussian"]["features"].endswith("family prior")
    # dead-time: the running scale and the identifier, then its mixture (mop.train.auto's step budget)
    budget, scale = PRESETS["small"].train.steps, STEP_COST["scale"]
    assert rows["one Gaussian"]["steps"] == steps_for(budget, scale * STEP_COST["identifier"])
    assert rows["auto"]["steps"] == steps_for(budget, scale * STEP_COST["mixture"])
    for row in rows.values():
        assert row["ms_per_step"] > 0
        assert row["cost_vs_plain"] == pytest.approx(row["ms_per_step"] / rows["plain"]["ms_per_step"])


def test_bench_features_refuses_no_rounds(capsys):
    assert main(["bench", "features", "--rounds", "0"]) != 0
    assert "--rounds must be at least 1" in capsys.readouterr().err
