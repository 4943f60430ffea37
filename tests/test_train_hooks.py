"""The loop's hooks (mop.train.TrainHooks) and the fine-tune's steps handed in through them
(mop.recipe.training): the source's weights at step 0 of a run that starts only, the step after the last on
the kept weights, a recipe key refused without its steps, and a stopped fine-tune resumed equal to one never
stopped (weights and the correction's gain)."""

import json

import numpy as np
import pytest
import torch

import mop.train as mt
from mop.checkpoint import load_tensors
from mop.cli import main
from mop.config import RunConfig, apply_overrides
from mop.errors import MopError
from mop.recipe.shrink import SHRINK_FILE
from tests.reference import sigint_during_step

pytestmark = pytest.mark.usefixtures("one_thread")


def tiny_config(**train) -> RunConfig:
    items = {
        "steps": 6,
        "batch_size": 4,
        "num_source_systems": 16,
        "horizon": 8,
        "log_every": 2,
        "checkpoint_every": 2,
        "device": "cpu",
        "compile": "off",
        **train,
    }
    overrides = ["model.num_layers=1", "model.width=16", "model.num_heads=2", "model.context=8"]
    return apply_overrides(RunConfig(), overrides + [f"train.{k}={json.dumps(v)}" for k, v in items.items()])


def weights(run_dir) -> dict[str, torch.Tensor]:
    return load_tensors(run_dir / "model.safetensors")[0]


def constant_start(config: RunConfig, model: torch.nn.Module) -> None:
    """Every parameter 0.01: a start no seed gives."""
    with torch.no_grad():
        for p in model.parameters():
            p.fill_(0.01)


def test_initial_weights_start_a_run_and_a_resumed_run_keeps_its_checkpoint(tmp_path, monkeypatch):
    """A run stopped at step 4 and resumed equals the run never stopped, both started from the hook's
    weights, which the resumed run does not load again (it would overwrite the checkpoint's); a run at
    lr 1e-30 keeps the hook's weights, so they are the start."""
    calls = []

    def start(config, model):
        calls.append(config.train.steps)
        constant_start(config, model)

    hooks = mt.TrainHooks(initial_weights=start)
    frozen = mt.train(tiny_config(steps=1, lr=1e-30), tmp_path / "frozen", progress=False, hooks=hooks)
    assert all(
        torch.allclose(w, torch.full_like(w, 0.01), rtol=0, atol=1e-12) for w in weights(frozen).values()
    )
    config = tiny_config()
    ref = mt.train(config, tmp_path / "ref", progress=False, hooks=hooks)
    plain = mt.train(config, tmp_path / "plain", progress=False)
    assert any(not torch.equal(weights(ref)[k], w) for k, w in weights(plain).items())
    restore = sigint_during_step(monkeypatch, 4)
    with pytest.raises(MopError, match="stopped by SIGINT at step 4"):
        mt.train(config, tmp_path / "run", progress=False, hooks=hooks)
    restore()
    calls.clear()
    mt.train(config, tmp_path / "run", progress=False, hooks=hooks)
    assert calls == []
    wa, wb = weights(ref), weights(tmp_path / "run")
    assert wa.keys() == wb.keys() and all(torch.equal(wa[k], wb[k]) for k in wa)


def test_the_step_after_the_last_sees_the_kept_weights_before_done(tmp_path):
    """With train.keep_best the model handed to `after` holds the weights model.safetensors keeps (the
    lowest validation loss), before done.json is written; check runs before anything, so its refusal leaves
    nothing behind; a finished run is reused without the step after."""
    seen = []

    def after(config, model, out_dir):
        kept = weights(out_dir)
        seen.append(all(torch.equal(v, kept[k]) for k, v in model.state_dict().items()))
        seen.append((out_dir / "done.json").exists())

    config = tiny_config(keep_best=True, lr=0.3)  # too high: the step-0 weights are kept
    run = mt.train(config, tmp_path / "run", progress=False, hooks=mt.TrainHooks(after=after))
    assert seen == [True, False]
    done = json.loads((run / "done.json").read_text())
    assert done["kept"] < done["step"]  # the kept weights are not the last step's

    def refuse(config):
        raise MopError("refused")

    with pytest.raises(MopError, match="refused"):
        mt.train(config, tmp_path / "never", progress=False, hooks=mt.TrainHooks(check=refuse))
    assert not (tmp_path / "never").exists()
    with pytest.raises(MopError, match="refused"):  # before the run directory is read: a finished one too
        mt.train(config, run, progress=False, hooks=mt.TrainHooks(check=refuse))
    seen.clear()
    mt.train(config, run, progress=False, hooks=mt.TrainHooks(after=after))
    assert seen == []


def test_a_recipe_key_without_the_recipe_steps_is_refused_in_one_line(tmp_path):
    """train.init and train.shrink_correction mean steps of the fine-tune recipe: the plain trainer refuses
    them rather than train without those steps."""
    for key in ('train.init="pretrained:lti-siso"', "train.shrink_correction=true"):
        config = apply_overrides(tiny_config(), [key])
        with pytest.raises(MopError) as err:
            mt.train(config, tmp_path / "run", progress=False)
        assert "\n" not in str(err.value) and key.split("=")[0] in str(err.value)
        assert "mop.recipe.training" in str(err.value)
        assert not (tmp_path / "run").exists()


def nearly_linear_record(path, T: int = 300) -> str:
    rng = np.random.default_rng(0)
    u = np.repeat(rng.uniform(-1, 1, size=T // 20 + 1), 20)[: T + 1]
    y = np.zeros(T + 1)
    for t in range(1, T):
        y[t + 1] = 1.5 * y[t] - 0.7 * y[t - 1] + np.tanh(0.8 * u[t])
    np.savez(path, y=(y + 0.05 * rng.normal(size=T + 1))[None, :, None], u=u[None, :, None])
    return str(path)


def test_a_stopped_fine_tune_resumed_equals_one_never_stopped(tmp_path, monkeypatch, capsys):
    """`mop train --data REC --init pretrained:lti-siso` (keep_best and the correction's gain chosen on
    the whole record, train.shrink_correction) stopped by Ctrl-C at step 5 and run again: the same weights,
    the same shrink.json and done.json as the fine-tune never stopped; and so with the default held-out
    choice (selection.json)."""
    data = nearly_linear_record(tmp_path / "est.npz")
    argv = ["train", "--data", data, "--init", "pretrained:lti-siso", "--no-progress"]
    argv += ["train.steps=8", "train.checkpoint_every=3"]
    held = [*argv, "--out", str(tmp_path / "held")]
    assert main(held) == 0
    restore = sigint_during_step(monkeypatch, 5)
    assert main([*argv, "--out", str(tmp_path / "held-b")]) != 0
    restore()
    assert main([*argv, "--out", str(tmp_path / "held-b")]) == 0
    for name in ("selection.json", "done.json"):
        a, b = (json.loads((tmp_path / run / name).read_text()) for run in ("held", "held-b"))
        assert a == b, name
    wa, wb = weights(tmp_path / "held"), weights(tmp_path / "held-b")
    assert all(torch.equal(wa[k], wb[k]) for k in wa)
    argv.append("train.shrink_correction=true")
    assert main([*argv, "--out", str(tmp_path / "a")]) == 0
    restore = sigint_during_step(monkeypatch, 5)
    assert main([*argv, "--out", str(tmp_path / "b")]) != 0
    restore()
    assert not (tmp_path / "b" / SHRINK_FILE).exists()
    assert main([*argv, "--out", str(tmp_path / "b")]) == 0
    wa, wb = weights(tmp_path / "a"), weights(tmp_path / "b")
    assert wa.keys() == wb.keys() and all(torch.equal(wa[k], wb[k]) for k in wa)
    for name in (SHRINK_FILE, "done.json"):
        a, b = (json.loads((tmp_path / run / name).read_text()) for run in ("a", "b"))
        assert a == b, name


def test_a_model_that_refuses_its_config_leaves_no_run_behind(tmp_path):
    """The GRU refuses the ARX feature when it is built: the trainer says so before it writes config.json,
    so the same folder then trains the config that builds (no 'holds a run with a different config')."""
    refused = apply_overrides(tiny_config(), ["model.arch=gru", "model.rls_order=2"])
    with pytest.raises(MopError, match="not of the GRU"):
        mt.train(refused, tmp_path / "run", progress=False)
    assert not (tmp_path / "run" / "config.json").exists()
    mt.train(apply_overrides(tiny_config(), ["model.arch=gru"]), tmp_path / "run", progress=False)
    assert (tmp_path / "run" / "done.json").is_file()
