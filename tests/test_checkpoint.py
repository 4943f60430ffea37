"""Checkpoints and weights: safetensors round trip, pickles and damaged files refused (never unpickled)."""

import pickle
import subprocess
import sys

import pytest
import torch

from mop.checkpoint import load_checkpoint, load_tensors, save_checkpoint
from mop.config import ModelConfig
from mop.errors import MopError
from mop.models import build_model
from mop.runs import load_predictor
from mop.train import make_optimizer, train
from tests.test_train import tiny_config

CFG = ModelConfig(num_layers=2, num_heads=2, width=32, context=10, input_dim=5, output_dim=5)

pytestmark = pytest.mark.usefixtures("one_thread")


def _trained_pair(seed: int):
    torch.manual_seed(seed)
    model = build_model(CFG)
    optimizer = make_optimizer(model, tiny_config().train, torch.device("cpu"))
    for _ in range(2):
        z = torch.randn(4, 10, 5)
        optimizer.zero_grad()
        model.loss(z, z).backward()
        optimizer.step()
    return model, optimizer


def test_checkpoint_round_trip(tmp_path):
    model, optimizer = _trained_pair(0)
    rng = {"data": torch.Generator().manual_seed(3).get_state()}
    save_checkpoint(tmp_path / "c.safetensors", 7, model, optimizer, rng)
    other, other_opt = _trained_pair(1)
    step, rng_back, _ = load_checkpoint(tmp_path / "c.safetensors", other, other_opt)
    assert step == 7 and torch.equal(rng_back["data"], rng["data"])
    for a, b in zip(model.state_dict().values(), other.state_dict().values(), strict=True):
        assert torch.equal(a, b)
    z = torch.randn(3, 10, 5)
    assert torch.equal(model(z), other(z))
    # the optimizer continues identically: one more step from both gives equal weights
    for m, opt in ((model, optimizer), (other, other_opt)):
        opt.zero_grad()
        m.loss(z, z).backward()
        opt.step()
    for a, b in zip(model.parameters(), other.parameters(), strict=True):
        assert torch.equal(a, b)


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    return train(tiny_config(steps=2), tmp_path_factory.mktemp("run"), progress=False)


def test_load_predictor_matches_model(run_dir):
    predictor = load_predictor(run_dir)
    tensors, _ = load_tensors(run_dir / "model.safetensors")
    for name, value in predictor.model.state_dict().items():
        assert torch.equal(value, tensors[name])


def test_pickle_weights_refused(run_dir, tmp_path, monkeypatch):
    bad = tmp_path / "run"
    bad.mkdir()
    (bad / "config.json").write_text((run_dir / "config.json").read_text())
    model = load_predictor(run_dir).model
    torch.save(model.state_dict(), bad / "model.safetensors")
    called = []
    monkeypatch.setattr(pickle, "load", lambda *a, **k: called.append(1))
    with pytest.raises(MopError, match="pickle"):
        load_predictor(bad)
    (bad / "model.safetensors").write_bytes(pickle.dumps(model.state_dict()))
    with pytest.raises(MopError, match="pickle"):
        load_predictor(bad)
    assert not called


def test_truncated_and_corrupted_weights_refused(run_dir, tmp_path):
    bad = tmp_path / "run"
    bad.mkdir()
    (bad / "config.json").write_text((run_dir / "config.json").read_text())
    data = (run_dir / "model.safetensors").read_bytes()
    (bad / "model.safetensors").write_bytes(data[: len(data) // 2])
    with pytest.raises(MopError, match="truncated or corrupted"):
        load_predictor(bad)
    (bad / "model.safetensors").write_bytes(b"\x07" * 64)
    with pytest.raises(MopError, match="truncated or corrupted"):
        load_predictor(bad)
    (bad / "model.safetensors").unlink()
    with pytest.raises(MopError, match="does not exist"):
        load_predictor(bad)
    with pytest.raises(MopError, match="does not exist"):
        load_predictor(tmp_path / "nowhere")


def _damage(path, nbytes=1000):
    """Overwrite `nbytes` inside the tensor data (same size), as a bad disk or a partial copy does."""
    data = bytearray(path.read_bytes())
    start = len(data) - nbytes - 200
    data[start : start + nbytes] = bytes((b + 1) % 256 for b in data[start : start + nbytes])
    path.write_bytes(bytes(data))


def test_overwritten_bytes_are_refused_in_one_line(tiny_run, tmp_path, capsys):
    import shutil

    import numpy as np

    from mop.cli import main

    run = tmp_path / "run"
    shutil.copytree(tiny_run, run)
    size = (run / "model.safetensors").stat().st_size
    _damage(run / "model.safetensors")
    assert (run / "model.safetensors").stat().st_size == size
    np.savez(tmp_path / "d.npz", y=np.zeros((1, 5, 2)))
    assert main(["predict", str(run), str(tmp_path / "d.npz"), "--out", str(tmp_path / "p.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "sha256" in err and str(run / "model.safetensors") in err, err
    assert f"mop train {run}/config.json --out {run} --fresh" in err
    assert not (tmp_path / "p.csv").exists()


def test_nan_weights_with_a_valid_digest_are_refused(tmp_path):
    from mop.checkpoint import save_tensors

    save_tensors(tmp_path / "w.safetensors", {"a": torch.tensor([1.0, float("nan")]), "b": torch.ones(2)})
    with pytest.raises(MopError, match="NaN/Inf in 1 tensors .first 'a'"):
        load_tensors(tmp_path / "w.safetensors")


def test_digest_is_over_names_and_bytes():
    from mop.checkpoint import tensors_digest

    a = {"x": torch.arange(4.0), "y": torch.zeros(2, dtype=torch.bfloat16)}
    assert tensors_digest(a) == tensors_digest(dict(reversed(list(a.items()))))  # order-free
    assert tensors_digest(a) != tensors_digest({**a, "x": torch.arange(4.0).flip(0)})
    assert tensors_digest(a) != tensors_digest({"z": a["x"], "y": a["y"]})


def test_fresh_retrains_a_damaged_run_to_the_same_weights(tiny_run, tmp_path, capsys):
    """The command the message names trains the run again in place; same seed, same weights."""
    import os
    import shutil

    from mop.cli import main

    run = tmp_path / "run"
    shutil.copytree(tiny_run, run)
    _damage(run / "model.safetensors")
    _damage(run / "checkpoint.safetensors")
    orphan = run / f".checkpoint.safetensors.{2**22 + 12345}.ab.tmp.safetensors"  # a killed write's copy
    orphan.write_bytes(b"\0" * 1000)
    assert not os.path.exists(f"/proc/{2**22 + 12345}")
    assert main(["train", str(run / "config.json"), "--out", str(run), "--fresh", "--no-progress"]) == 0
    assert not orphan.exists()
    ref = tmp_path / "ref"  # the same config trained here (same thread count: bitwise comparable)
    assert main(["train", str(tiny_run / "config.json"), "--out", str(ref), "--no-progress"]) == 0
    fresh, _ = load_tensors(run / "model.safetensors")
    original, _ = load_tensors(ref / "model.safetensors")
    assert fresh.keys() == original.keys() and all(torch.equal(fresh[k], original[k]) for k in fresh)
    lines = (run / "metrics.jsonl").read_text().splitlines()
    assert len(lines) == len((ref / "metrics.jsonl").read_text().splitlines())  # not appended twice


def test_damaged_checkpoint_on_resume_names_the_fix(tmp_path):
    cfg = tiny_config()
    out = train(cfg, tmp_path / "run", progress=False)
    (out / "done.json").unlink()
    _damage(out / "checkpoint.safetensors")
    with pytest.raises(MopError, match="checkpoint.safetensors is damaged.*--fresh"):
        train(cfg, out, progress=False)


def test_diverged_before_any_checkpoint_says_so(tmp_path):
    import dataclasses

    cfg = tiny_config()
    cfg = dataclasses.replace(cfg, train=dataclasses.replace(cfg.train, lr=1e9, checkpoint_every=1000))
    with pytest.raises(MopError) as err:
        train(cfg, tmp_path / "run", progress=False)
    text = str(err.value)
    assert "before the first checkpoint, so no weights were saved" in text and "step 0" not in text, text
    assert "train.lr (it is 1e+09)" in text
    assert not (tmp_path / "run" / "model.safetensors").exists()


def test_a_header_length_starting_with_0x80_is_not_a_pickle(tmp_path):
    """safetensors files begin with the header's length; 0x80 as its low byte once read as a pickle."""
    from mop.checkpoint import save_tensors

    for pad in range(300):  # metadata of growing length: some header length is 0x80 mod 256
        path = tmp_path / "w.safetensors"
        save_tensors(path, {"a": torch.ones(2)}, {"pad": "x" * pad})
        if path.read_bytes()[0] == 0x80:
            break
    else:
        pytest.fail("no header length with low byte 0x80")
    tensors, metadata = load_tensors(path)
    assert torch.equal(tensors["a"], torch.ones(2)) and metadata["pad"] == "x" * pad


WRITE_ONCE = """
import sys, torch
from mop.checkpoint import save_tensors
tensors = {"a": torch.arange(6.0).reshape(2, 3), "b": torch.ones(4, dtype=torch.float64)}
save_tensors(sys.argv[1], tensors, {"format": "pt", "mop": "{}", "zz": "1"})
"""


def test_the_same_tensors_give_the_same_bytes_in_every_process(tmp_path):
    """The Rust writer orders metadata keys by a per-process hash; save_tensors sorts them, so pretrained
    builds (which record the files' sha256) are reproducible. Without the sort, four processes writing three
    keys agree with probability (1/6)^3."""
    paths = [tmp_path / f"w{i}.safetensors" for i in range(4)]
    for path in paths:
        subprocess.run([sys.executable, "-c", WRITE_ONCE, str(path)], check=True)
    assert len({p.read_bytes() for p in paths}) == 1
    tensors, meta = load_tensors(paths[0])
    assert meta["zz"] == "1" and torch.equal(tensors["a"], torch.arange(6.0).reshape(2, 3))
