"""mop bench recipe: time-limited training per recipe, scored by the MOP/KF ratio on seeded test systems."""

import json
import math

import pytest
import torch

from mop.bench.recipe import BUILTIN, TestSet, parse_recipe
from mop.cli import main
from mop.errors import MopError
from mop.predictors import make_predictor

TINY = ["tiny", "model.num_layers=1", "model.width=16", "model.num_heads=2", "train.batch_size=8"]


def test_json_schema_each_step_budget_trains_its_steps(tmp_path, capsys):
    """Step budgets, so nothing depends on the machine's speed (wall-clock budgets are what the benchmark
    itself measures): each row trains exactly its budget of steps and is scored on the same test set."""
    argv = ["bench", "recipe", "--steps", "2", "5", "--systems", "16", "--recipe", *TINY]
    assert main([*argv, "--out", str(tmp_path), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["unit"] == "steps" and result["num_test_systems"] == 16 and result["window"] == [20, 51]
    assert [r["name"] for r in result["recipes"]] == ["tiny"]
    rows = result["results"]
    assert [r["budget"] for r in rows] == [2, 5] and [r["steps"] for r in rows] == [2, 5]
    keys = {"recipe", "budget", "unit", "steps", "seconds", "steps_per_s", "train_loss", "ratio", "ci_low"}
    assert keys <= set(rows[0])
    for r in rows:
        assert math.isfinite(r["ratio"]) and r["ratio"] > 0 and r["ci_low"] <= r["ratio"] <= r["ci_high"]
        assert r["unit"] == "steps" and r["seconds"] > 0 and r["steps_per_s"] > 0
    assert all((tmp_path / f"bench-recipe.{ext}").exists() for ext in ("png", "pdf"))


def test_step_budgets_are_deterministic(tmp_path, capsys):
    argv = ["bench", "recipe", "--steps", "3", "--systems", "8", "--recipe", *TINY, "--json"]
    ratios = []
    for _ in range(2):
        assert main([*argv, "--out", str(tmp_path)]) == 0
        (row,) = json.loads(capsys.readouterr().out)["results"]
        assert row["steps"] == 3 and row["unit"] == "steps"
        ratios.append(row["ratio"])
    assert ratios[0] == ratios[1]


def test_recipes_are_data():
    r = parse_recipe(["mine", "base=paper", "model.num_layers=2", "warmup=0.1", "final_lr=0.1"])
    cfg = r.config()
    assert (cfg.model.num_layers, cfg.model.width, r.warmup) == (2, 256, 0.1)
    assert r.lr_factor(0.05, cfg.train) == pytest.approx(0.5)
    paper = BUILTIN["paper"].config()
    assert (paper.model.num_layers, paper.train.lr, paper.train.lr_schedule) == (12, 3e-4, "constant")
    assert BUILTIN["paper"].lr_factor(0.0, paper.train) == 1.0
    cosine = parse_recipe(["c", "train.lr_schedule=cosine", "warmup=0", "final_lr=0"])
    assert cosine.lr_factor(0.5, cosine.config().train) == pytest.approx(0.5)
    with pytest.raises(MopError):
        parse_recipe(["bad", "model.nope=1"])


def test_family_reference_and_seeds(tmp_path, capsys):
    """--seeds 2 trains two seeds (different ratios, range around the mean); --family/--reference/--compare
    score against that family's predictor; an unknown name is refused before any training."""
    argv = ["bench", "recipe", "--steps", "2", "--systems", "8", "--seeds", "2", "--recipe", *TINY]
    argv += ["--family", "upper-triangular", "--reference", "kalman", "--compare", "rls", "--json"]
    assert main([*argv, "--out", str(tmp_path)]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["family"] == "upper-triangular" and result["seeds"] == 2 and "rls" in result["compare"]
    (row,) = result["results"]
    ratios = [s["ratio"] for s in row["seeds"]]
    assert [s["seed"] for s in row["seeds"]] == [0, 1] and ratios[0] != ratios[1]
    assert row["ratio"] == pytest.approx(sum(ratios) / 2)
    assert (row["ratio_min"], row["ratio_max"]) == (min(ratios), max(ratios))
    assert main(["bench", "recipe", "--family", "nope", "--steps", "1"]) == 2
    assert "unknown --family 'nope'" in capsys.readouterr().err


def test_forecast_reports_k_step_errors_whose_first_is_the_one_step_error(tmp_path, capsys):
    """--forecast K: each recipe's and the reference's k-step errors; k = 1 is the mean one-step error norm
    over t >= 20, computed here from predict alone."""
    argv = ["bench", "recipe", "--steps", "2", "--systems", "8", "--seeds", "2", "--recipe", *TINY]
    assert main([*argv, "--forecast", "3", "--compare", "rls", "--out", str(tmp_path), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    (row,) = result["results"]
    per_seed = [s["k_step"] for s in row["seeds"]]
    assert len(row["k_step"]) == 3 and row["k_step"] == pytest.approx(
        [sum(c) / 2 for c in zip(*per_seed, strict=True)]
    )
    test = TestSet(8, 0)
    one_step = (make_predictor("kalman").predict(test.traj) - test.traj.y)[:, 20:].norm(dim=-1).mean()
    assert result["k_step"]["kalman"][0] == pytest.approx(float(one_step), rel=1e-9)
    kf = result["k_step"]["kalman"]
    assert kf[0] < kf[1] < kf[2] and set(result["k_step"]) == {"kalman", "rls"}
    assert torch.isfinite(torch.tensor(per_seed)).all()
