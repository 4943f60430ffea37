"""`mop reproduce --jobs N` (mop.experiments.schedule): the runs every unit trains are planned ahead and
trained as tasks of their own, the longest first, and each (experiment, seed) unit runs once its runs are
trained; the numbers equal those of --jobs 1 in this process."""

import json

from mop import cli
from mop.experiments.planning import planned_runs
from mop.experiments.schedule import next_task, training_cost
from mop.train import resolve_config


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
    from mop.config import RunConfig, apply_overrides

    def cost(*keys):
        return training_cost(apply_overrides(RunConfig(), ["model.num_layers=2", "model.width=64", *keys]))

    base = cost("train.steps=600", "train.horizon=50", "model.context=50")
    assert cost("train.steps=1200", "train.horizon=50", "model.context=50") == 2 * base
    ratio = cost("train.steps=600", "train.horizon=100", "model.context=100") / base
    assert 2.1 < ratio < 2.3


def test_a_unit_without_a_shipped_model_is_skipped_by_the_errors_type(tmp_path, monkeypatch):
    """`reproduce all --pretrained` skips an experiment with no shipped model (NoPretrainedModel, raised
    before any work) and stops on any other MopError, whatever its text says."""
    import dataclasses

    import pytest

    import mop.experiments.schedule as schedule
    from mop.errors import MopError, NoPretrainedModel
    from mop.experiments import get_experiment

    exp, out = get_experiment("noise-shift"), tmp_path / "noise-shift"
    skip = schedule.UnitSettings("smoke", 0, [], {}, pretrained=True, skip_missing=True)
    result = schedule.run_unit(exp, 0, out, 1, False, skip)
    assert result.eval is None and "skipped (noise-shift [" in result.message and not out.exists()
    with pytest.raises(NoPretrainedModel):
        schedule.run_unit(exp, 0, out, 1, False, dataclasses.replace(skip, skip_missing=False))

    def fails(*args, **kwargs):
        raise MopError("no pretrained model is shipped, says this other error")

    monkeypatch.setattr(schedule, "run_experiment", fails)
    with pytest.raises(MopError, match="this other error"):
        schedule.run_unit(exp, 0, out, 1, False, skip)
