"""Checkpoints and weights: safetensors round trip, pickles and damaged files refused (never unpickled)."""

import pickle

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
