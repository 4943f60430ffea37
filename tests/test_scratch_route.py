"""A run from scratch is one downward sequence on a record in memory (mop.recipe.layers.scratch_config): the
record is split once, its training part handed to the plan once (RecordedData.training_part), the plan
(mop.recipe.records.plan_records) is a pure function of that part, the config and the budget, nothing on the
way reads a file, and none of the fine-tune's steps (mop.recipe.finetune) is taken."""

import builtins

import numpy as np

import mop.recipe.finetune
import mop.recipe.layers
import mop.record
from mop.config import DataConfig
from mop.recipe.layers import scratch_config, training_config
from mop.recipe.plan import RECORDS_BODY
from mop.recipe.records import plan_records
from mop.record import Record
from mop.train.records import RecordedData, TrainingPart, TrainingRecords


def plant(T: int = 400, seed: int = 0) -> Record:
    """A second-order ARX plant with a mild cubic term, driven by noise."""
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(T, 1))
    y = np.zeros((T, 1))
    for t in range(2, T):
        y[t] = 1.4 * y[t - 1] - 0.6 * y[t - 2] + 0.3 * u[t - 1] - 0.05 * y[t - 1] ** 3 + 0.01 * rng.normal()
    return Record(y=y, u=u, name=f"plant{seed}")


def _refuse(*args, **kwargs):
    raise AssertionError("a run from scratch read a file or took a fine-tune's step")


def test_plan_records_is_a_pure_function_of_the_training_part():
    config = training_config(None, "small")
    part = TrainingRecords((plant(500, 0),)).split(DataConfig(path="r")).training_part
    first = plan_records(part, config, budget=1.0)
    plan_records(TrainingRecords((plant(700, 3),)).split(DataConfig(path="s")).training_part, config, 2.0)
    assert plan_records(part, config, budget=1.0) == first  # whatever was planned in between
    again = TrainingRecords((plant(500, 0),)).split(DataConfig(path="r")).training_part
    assert plan_records(again, config, budget=1.0) == first  # the same record, split afresh
    assert first.p > 0 and first.steps >= 1000


def test_scratch_config_splits_once_reads_nothing_and_never_fine_tunes(monkeypatch):
    records = TrainingRecords((plant(500, 0),), source="in memory")
    expected = scratch_config(None, None, records, [], None)[0]
    splits, parts = [], []
    init = RecordedData.__init__
    monkeypatch.setattr(RecordedData, "__init__", lambda self, *a: splits.append(1) or init(self, *a))
    made = TrainingPart.__init__
    monkeypatch.setattr(TrainingPart, "__init__", lambda self, *a: parts.append(1) or made(self, *a))
    fine_tune_steps = ("fine_tune_config", "with_fine_tuning", "with_records_recipe", "with_records_body")
    for name in (*fine_tune_steps, "with_record_prior"):
        monkeypatch.setattr(mop.recipe.finetune, name, _refuse)
    monkeypatch.setattr(mop.recipe.layers, "fine_tune_config", _refuse)
    monkeypatch.setattr(builtins, "open", _refuse)
    monkeypatch.setattr(mop.record, "read_timed", _refuse)
    fresh = TrainingRecords((plant(500, 0),), source="in memory")
    config, given, record = scratch_config(None, None, fresh, [], None)
    assert config == expected and config.model.arch == RECORDS_BODY["model.arch"]  # the records recipe's
    assert given is fresh and record is fresh.split(config.data)
    assert (len(splits), len(parts)) == (1, 1)  # split once, the plan's arrays made once


def test_a_fine_tune_of_the_records_body_start_trains_as_the_records_recipe_from_scratch(tmp_path):
    """`mop train --data REC --init pretrained:cascaded-tanks-lru` (a records start without a feature: the
    records recipe's own deep LRU) trains as `mop train --data REC` from random weights does, from the
    source's weights: the same network, batch, windows, simulated tails, learning rate, schedule and the
    steps of the same budget; only the source and the kept weights (train.keep_best) differ."""
    import mop.train as mt
    from mop.experiments import get_experiment, run_config
    from mop.recipe.finetune import fine_tune_config

    wide = ["train.steps=1", "model.context=200", "train.horizon=200"]  # the records body's windows
    source = run_config(get_experiment("class-cascaded-tanks-lru"), "smoke", overrides=wide)
    source_dir = mt.train(source, tmp_path / "start", progress=False)
    records = TrainingRecords((plant(700, 0),), source="in memory")
    scratch = scratch_config(None, None, records, [], 2.0)[0]
    tuned = fine_tune_config(None, None, records, [], str(source_dir), 2.0)[0]
    assert tuned.model.arch == scratch.model.arch == RECORDS_BODY["model.arch"]
    assert tuned.model.rls_order == scratch.model.rls_order == 0
    same = ("batch_size", "horizon", "simulate_after", "lr", "lr_schedule", "warmup_steps", "steps")
    assert {k: getattr(tuned.train, k) for k in same} == {k: getattr(scratch.train, k) for k in same}
    assert tuned.train.horizon == scratch.train.horizon == 200
    assert tuned.train.init == str(source_dir) and tuned.train.context_prefix == 0
