"""`mop reproduce --seeds K`: same test systems, K training seeds, mean/range/CI per ratio; the report's
distance to the best predictor; the summary table of `reproduce all` (mop.experiments.seeds)."""

import json

import numpy as np
import pytest

from mop import cli
from mop.experiments.evaluating import distance_to_best
from mop.experiments.seeds import lead_table, seed_summary, seeds_table
from mop.metrics import mse_ratio_ci
from mop.train import resolve_config


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
    assert "## Distance to the best predictor" in report and "1.025" in report  # beside the authors'


def test_reproduce_seeds_must_be_positive(capsys):
    assert cli.main(["reproduce", "linear", "--seeds", "0"]) == 2
    assert "--seeds must be at least 1" in capsys.readouterr().err


def test_jobs_run_the_seeds_in_worker_processes_with_the_same_numbers(tmp_path, one_thread, capsys):
    """--jobs 2 trains and evaluates each seed in its own process (one torch thread): the same eval.json
    numbers as --jobs 1 in this process (one thread too), in separate run directories."""
    keys = ["train.steps=3", "train.batch_size=8", "train.checkpoint_every=3"]
    evals = {}
    for jobs in (1, 2):
        out, runs = tmp_path / f"j{jobs}", tmp_path / f"runs{jobs}"
        argv = ["reproduce", "linear", "--preset", "smoke", "--out", str(out), "--runs", str(runs)]
        assert cli.main([*argv, "--quiet", "--seeds", "2", "--jobs", str(jobs), *keys]) == 0
        evals[jobs] = [json.loads((out / f"seed-{s}" / "eval.json").read_text()) for s in (0, 1)]
        assert (out / "seeds.md").is_file() and len(list(runs.iterdir())) == 2
    for one, two in zip(evals[1], evals[2], strict=True):
        assert one["predictors"]["mop"]["error"] == two["predictors"]["mop"]["error"]
        assert one["to_best"] == two["to_best"]
    assert evals[2][0]["predictors"]["mop"]["error"] != evals[2][1]["predictors"]["mop"]["error"]


def test_jobs_must_be_positive(capsys):
    assert cli.main(["reproduce", "linear", "--jobs", "0"]) == 2
    assert "--jobs must be at least 1" in capsys.readouterr().err


def test_planned_runs_are_the_runs_the_experiment_trains(tmp_path, one_thread):
    """planned_runs (what --jobs trains ahead) names exactly the run directories run_experiment creates,
    for an experiment that trains five runs over its conditions (scaling), and the configs they train."""
    from mop.experiments import get_experiment
    from mop.experiments.planning import planned_runs
    from mop.experiments.runner import run_experiment
    from mop.runs import load_config

    keys = ["train.steps=2", "train.batch_size=4", "train.checkpoint_every=2"]
    exp, runs = get_experiment("scaling"), tmp_path / "runs"
    planned = planned_runs(exp, "smoke", seed=0, train_seed=0, runs_dir=runs, overrides=keys)
    run_experiment(exp, "smoke", tmp_path / "out", seed=0, runs_dir=runs, overrides=keys, progress=False)
    assert len(planned) == 5
    assert sorted(run for _, run in planned) == sorted(str(p) for p in runs.iterdir())
    for config, run in planned:
        assert load_config(run) == resolve_config(config)


def test_jobs_train_an_experiments_runs_as_their_own_tasks_with_the_same_numbers(tmp_path, one_thread):
    """--jobs 2 trains the two runs of calibration (linear and colored noise) as two tasks, then evaluates:
    the same eval.json numbers as --jobs 1."""
    keys = ["train.steps=3", "train.batch_size=8", "train.checkpoint_every=3"]
    evals = {}
    for jobs in (1, 2):
        out, runs = tmp_path / f"j{jobs}", tmp_path / f"runs{jobs}"
        argv = ["reproduce", "calibration", "--preset", "smoke", "--out", str(out), "--runs", str(runs)]
        assert cli.main([*argv, "--quiet", "--jobs", str(jobs), *keys]) == 0
        evals[jobs] = json.loads((out / "eval.json").read_text())
        assert len(list(runs.iterdir())) == 2

    def untimed(condition: dict) -> dict:  # every number but the wall times
        return {p: {k: v for k, v in r.items() if k != "seconds"} for p, r in condition["predictors"].items()}

    for name, one in evals[1]["conditions"].items():
        two = evals[2]["conditions"][name]
        assert untimed(one) == untimed(two) and one["to_best"] == two["to_best"]


def test_next_task_starts_ready_units_first_then_the_trainings_in_their_order():
    """The scheduler of --jobs: a unit whose runs are all trained goes before any training; otherwise the
    trainings go in their given order (longest first); a unit waits until every run it needs is trained."""
    from mop.commands.reproduce import next_task

    waiting, needs, trained, trainings = [0, 1, 2], [{"a", "b"}, {"c"}, set()], set(), ["b", "c", "a"]
    assert next_task(waiting, needs, trained, trainings) == ("unit", 2)  # needs nothing
    assert next_task(waiting, needs, trained, trainings) == ("run", "b")
    trained.add("b")  # unit 0 still needs "a"
    assert next_task(waiting, needs, trained, trainings) == ("run", "c")
    trained.add("c")
    assert next_task(waiting, needs, trained, trainings) == ("unit", 1)  # ahead of the waiting training "a"
    assert next_task(waiting, needs, trained, trainings) == ("run", "a")
    assert next_task(waiting, needs, trained, trainings) is None  # unit 0 waits for "a" to finish
    trained.add("a")
    assert next_task(waiting, needs, trained, trainings) == ("unit", 0)
    assert waiting == [] and trainings == []


def test_training_cost_orders_by_steps_tokens_and_width():
    """The longest training first: cost grows with steps, horizon and width as a transformer's work does
    (scaling's context-100 run costs 2.2x its 50-step twin, measured 98 s against 43 s)."""
    from mop.commands.reproduce import training_cost
    from mop.config import RunConfig, apply_overrides

    def cost(*keys):
        return training_cost(apply_overrides(RunConfig(), ["model.num_layers=2", "model.width=64", *keys]))

    base = cost("train.steps=600", "train.horizon=50", "model.context=50")
    assert cost("train.steps=1200", "train.horizon=50", "model.context=50") == 2 * base
    ratio = cost("train.steps=600", "train.horizon=100", "model.context=100") / base
    assert 2.1 < ratio < 2.3
