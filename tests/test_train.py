"""The trainer: resume equals not stopping (bit for bit on CPU), SIGKILL + resume, NaN stop, reuse, config."""

import dataclasses
import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

import mop.train as mt
import mop.train.loop
from mop.checkpoint import load_checkpoint, load_tensors
from mop.config import RunConfig, apply_overrides, from_dict, to_dict
from mop.errors import MopError
from mop.models import build_model
from mop.runs import load_predictor
from tests.reference import sigint_during_step

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "OMP_NUM_THREADS": "1"}


pytestmark = pytest.mark.usefixtures("one_thread")


def tiny_config(steps: int = 6, **train) -> RunConfig:
    items = {
        "steps": steps,
        "batch_size": 4,
        "num_source_systems": 16,
        "horizon": 8,
        "log_every": 2,
        "checkpoint_every": 2,
        "device": "cpu",
        "compile": "off",
        "deterministic": True,
        **train,
    }
    overrides = [
        "model.num_layers=2",
        "model.width=32",
        "model.num_heads=2",
        "model.context=8",
        "system.state_dim=3",
        "system.output_dim=2",
    ]
    return apply_overrides(RunConfig(), overrides + [f"train.{k}={json.dumps(v)}" for k, v in items.items()])


def weights(run_dir: Path) -> dict:
    return load_tensors(run_dir / "model.safetensors")[0]


def assert_same_weights(a: Path, b: Path) -> None:
    wa, wb = weights(a), weights(b)
    assert wa.keys() == wb.keys()
    for key in wa:
        assert torch.equal(wa[key], wb[key]), key


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    return mt.train(tiny_config(), tmp_path_factory.mktemp("ref"), progress=False)


@pytest.mark.parametrize("num_source_systems", [16, 0])
def test_resume_equals_uninterrupted(tmp_path, monkeypatch, num_source_systems, reference):
    config = tiny_config(num_source_systems=num_source_systems)
    ref = reference if num_source_systems else mt.train(config, tmp_path / "ref", progress=False)
    restore = sigint_during_step(monkeypatch, 4)  # Ctrl-C arrives during the 4th step
    with pytest.raises(MopError, match="stopped by SIGINT at step 4"):
        mt.train(config, tmp_path / "run", progress=False)
    assert not (tmp_path / "run" / "done.json").exists()
    assert load_checkpoint(tmp_path / "run" / "checkpoint.safetensors", *_fresh(config))[0] == 4
    restore()
    mt.train(config, tmp_path / "run", progress=False)
    assert_same_weights(ref, tmp_path / "run")
    steps = [
        r["step"]
        for r in map(json.loads, (tmp_path / "run" / "metrics.jsonl").read_text().splitlines())
        if "loss" in r
    ]
    assert steps == [2, 4, 6]


def _fresh(config):
    config = mt.resolve_config(config)
    model = build_model(config.model)
    return model, mt.make_optimizer(model, config.train, torch.device("cpu"))


def test_sigkill_three_times_then_resume(tmp_path):
    config = tiny_config(steps=80, checkpoint_every=1)  # long enough that no run finishes before its kill
    reference = mt.train(config, tmp_path / "reference", progress=False)
    (tmp_path / "config.json").write_text(json.dumps(to_dict(config)))
    run = tmp_path / "run"
    code = (
        "import json,sys; from mop.config import RunConfig, from_dict; from mop.train import train; "
        "train(from_dict(RunConfig, json.load(open(sys.argv[1]))), sys.argv[2], progress=False)"
    )
    command = [sys.executable, "-c", code, str(tmp_path / "config.json"), str(run)]
    rand, killed = random.Random(0), 0
    for _ in range(3):
        proc = subprocess.Popen(command, cwd=ROOT, env=ENV, stderr=subprocess.DEVNULL)
        start, deadline = _mtime(run / "checkpoint.safetensors"), time.time() + 60
        while time.time() < deadline and proc.poll() is None:  # new checkpoint, then kill at random
            if _mtime(run / "checkpoint.safetensors") > start:
                break
            time.sleep(0.005)
        time.sleep(rand.uniform(0.0, 0.05))
        proc.kill()
        killed += proc.wait() == -signal.SIGKILL
    assert killed == 3, "every run should have been killed mid-training"
    assert subprocess.run(command, cwd=ROOT, env=ENV).returncode == 0
    assert_same_weights(reference, run)


def _mtime(path: Path) -> int:
    return path.stat().st_mtime_ns if path.exists() else 0


def test_nan_loss_stops_and_keeps_last_good_checkpoint(tmp_path, monkeypatch):
    batch, calls = mt.TrainingData.batch, []

    def poisoned_batch(self):
        calls.append(1)
        inputs, targets = batch(self)
        return (inputs * float("nan"), targets) if len(calls) == 3 else (inputs, targets)

    monkeypatch.setattr(mt.TrainingData, "batch", poisoned_batch)
    with pytest.raises(MopError, match="loss became nan.*step 2"):
        mt.train(tiny_config(), tmp_path, progress=False)
    step, _, _ = load_checkpoint(tmp_path / "checkpoint.safetensors", *_fresh(tiny_config()))
    assert step == 2
    assert all(torch.isfinite(v).all() for v in weights(tmp_path).values())
    assert not (tmp_path / "done.json").exists()


def test_finished_run_is_reused_and_other_config_refused(reference, monkeypatch):
    before = (reference / "model.safetensors").stat().st_mtime_ns
    never = lambda cfg: pytest.fail("a finished run must not train again")  # noqa: E731
    monkeypatch.setattr(mop.train.loop, "build_model", never)
    assert mt.train(tiny_config(), reference, progress=False) == reference
    assert (reference / "model.safetensors").stat().st_mtime_ns == before
    with pytest.raises(MopError, match="different config.*train.lr"):
        mt.train(tiny_config(lr=1e-3), reference, progress=False)


def test_config_json_rebuilds_model(reference):
    config = from_dict(RunConfig, json.loads((reference / "config.json").read_text()))
    assert (config.model.input_dim, config.model.output_dim) == (2, 2)
    predictor = load_predictor(reference)
    assert predictor.cfg == config.model


@pytest.mark.parametrize(
    "bad, message",
    [
        ({"train": {"stepz": 3}}, "unknown config key 'train.stepz'"),
        ({"train": {"batch_size": -4}}, "train.batch_size must be a positive integer"),
        ({"model": {"width": -32}}, "model.width must be a positive integer"),
        ({"train": {"num_source_systems": -1}}, "num_source_systems must be >= 0"),
    ],
)
def test_config_validation(bad, message):
    with pytest.raises(MopError, match=message):
        from_dict(RunConfig, bad)


def test_model_dims_must_match_family():
    with pytest.raises(MopError, match="does not match"):
        mt.resolve_config(apply_overrides(tiny_config(), ["model.output_dim=7"]))


def test_handed_over_model_predicts_what_the_reloaded_run_does(tmp_path, monkeypatch):
    """train_model hands the trained model to its predictor (the runner loads no weights for a run it
    has just trained); its predictions equal, bit for bit, those of the run reloaded from disk."""
    import mop.runs
    from mop.experiments import get_experiment
    from mop.experiments.planning import Session, learned_predictor
    from mop.predictors import make_predictor
    from mop.systems import generator, make_family

    def no_reload(*args, **kwargs):
        raise AssertionError("the runner reloaded the model it had just trained")

    config = tiny_config()
    config = dataclasses.replace(config, model=dataclasses.replace(config.model, readout="gaussian"))
    session = Session(get_experiment("linear"), "smoke", 0, tmp_path, [], False, {})
    with monkeypatch.context() as patch:
        patch.setattr(mop.runs, "load_predictor", no_reload)
        patch.setattr(mop.runs, "load_model", no_reload)
        handed = learned_predictor(session, "mop", get_experiment("linear").conditions[0], config)
    (run_dir,) = session.runs.values()
    reloaded = make_predictor("mop", run_dir=run_dir)
    assert handed.name == reloaded.name == "mop" and not handed.model.training
    traj = make_family(config.system).generate(5, 8, generator=generator(11))
    assert torch.equal(handed.predict(traj), reloaded.predict(traj))
    for a, b in zip(handed.predict_distribution(traj), reloaded.predict_distribution(traj), strict=True):
        assert torch.equal(a, b)
    again = mt.train_model(config, run_dir, progress=False)  # a finished run: loaded from disk
    assert all(torch.equal(a, b) for a, b in zip(again.parameters(), handed.model.parameters(), strict=True))


def test_a_saved_config_with_tuple_knobs_is_the_same_config(tmp_path):
    """config.json holds a tuple knob (a family's range) as a list: the run is still reused, not refused."""
    from mop.systems.linear import LinearConfig
    from mop.train.rundir import check_run_dir

    @dataclasses.dataclass(frozen=True)
    class BandConfig(LinearConfig):
        band: tuple[float, float] = (0.1, 0.2)

    config = dataclasses.replace(tiny_config(), system=BandConfig(family="linear"))
    (tmp_path / "config.json").write_text(json.dumps(to_dict(config)))
    (tmp_path / "done.json").write_text("{}")
    assert check_run_dir(tmp_path, config)
    with pytest.raises(MopError, match="different config"):
        check_run_dir(
            tmp_path, dataclasses.replace(config, system=BandConfig(family="linear", band=(0.1, 0.3)))
        )
