"""train.keep_best: model.safetensors holds the weights of the lowest validation loss, step 0 included.
Against runs stopped at each checkpoint (a constant learning rate, so a run of s steps is the first s steps
of a longer one), the validation loss recomputed on the kept weights, a harmful learning rate (step 0's
weights kept), and resume == uninterrupted."""

import json

import pytest
import torch

import mop.train as mt
from mop.errors import MopError
from mop.models import build_model
from mop.train.data import validation_batch
from mop.train.optim import validation_loss
from tests.reference import sigint_during_step
from tests.test_train import assert_same_weights, tiny_config, weights

pytestmark = pytest.mark.usefixtures("one_thread")


def val_records(run) -> list[tuple[int, float]]:
    lines = (run / "metrics.jsonl").read_text().splitlines()
    return [(r["step"], r["val_loss"]) for r in map(json.loads, lines) if "val_loss" in r]


def test_kept_weights_are_the_checkpoint_of_the_lowest_validation_loss(tmp_path):
    config = tiny_config(steps=6, keep_best=True, lr=3e-2)
    run = mt.train(config, tmp_path / "best", progress=False)
    records = val_records(run)
    assert [s for s, _ in records] == [0, 2, 4, 6]  # step 0 is a candidate
    kept_step, kept_val = min(records, key=lambda r: r[1])
    assert json.loads((run / "done.json").read_text()) == {"step": 6, "kept": kept_step}
    # the same weights as a run stopped at that step (no keep_best: its model.safetensors is its last)
    if kept_step > 0:
        short = mt.train(tiny_config(steps=kept_step, lr=3e-2), tmp_path / "short", progress=False)
        assert_same_weights(short, run)
    # and their validation loss, recomputed, is the lowest logged
    resolved = mt.resolve_config(config)
    model = build_model(resolved.model)
    model.load_state_dict(weights(run))
    cpu = torch.device("cpu")
    val = validation_batch(resolved, cpu)
    assert validation_loss(model, val, resolved.train, cpu) == pytest.approx(kept_val, rel=1e-6)
    assert all(kept_val <= v for _, v in records)


def test_training_that_only_hurts_keeps_the_starting_weights(tmp_path):
    """lr = 3: every step makes the model worse than the one it starts as, so model.safetensors holds the
    initial weights (those of build_model under the run's seed) and done.json says step 0."""
    config = tiny_config(steps=4, keep_best=True, lr=3.0)
    run = mt.train(config, tmp_path / "run", progress=False)
    records = val_records(run)
    assert records[0][0] == 0 and all(v > records[0][1] for _, v in records[1:])
    assert json.loads((run / "done.json").read_text())["kept"] == 0
    torch.manual_seed(config.train.seed)
    start = build_model(mt.resolve_config(config).model).state_dict()
    kept = weights(run)
    assert kept.keys() == start.keys() and all(torch.equal(kept[k], start[k]) for k in kept)


def test_resume_equals_uninterrupted_with_keep_best(tmp_path, monkeypatch):
    config = tiny_config(steps=6, keep_best=True, lr=3e-2)
    ref = mt.train(config, tmp_path / "ref", progress=False)
    restore = sigint_during_step(monkeypatch, 4)
    with pytest.raises(MopError, match="stopped by SIGINT at step 4"):
        mt.train(config, tmp_path / "run", progress=False)
    restore()
    mt.train(config, tmp_path / "run", progress=False)
    assert_same_weights(ref, tmp_path / "run")
    assert (ref / "done.json").read_text() == (tmp_path / "run" / "done.json").read_text()
    assert val_records(ref) == val_records(tmp_path / "run")
