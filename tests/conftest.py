import dataclasses

import pytest
import torch

from mop.config import RunConfig, apply_overrides


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory):
    """A tiny trained run dir (2 layers, width 32, 20 steps, m=2, context 10), once per session."""
    from mop.train import train

    cfg = apply_overrides(
        RunConfig(),
        [
            "system.output_dim=2",
            "system.state_dim=2",
            "model.num_layers=2",
            "model.width=32",
            "model.num_heads=2",
            "model.context=10",
            "train.steps=20",
            "train.horizon=10",
        ],
    )
    return train(cfg, tmp_path_factory.mktemp("run") / "tiny", progress=False)


@pytest.fixture
def tiny_smoke(monkeypatch):
    """The smoke preset cut further (fewer steps and test systems) to keep the test suite fast."""
    from mop import experiments

    p = experiments.PRESETS["smoke"]
    tiny = dataclasses.replace(
        p,
        train=dataclasses.replace(p.train, steps=3, batch_size=8, log_every=1, checkpoint_every=3),
        num_test_systems=6,
    )
    monkeypatch.setitem(experiments.PRESETS, "smoke", tiny)


@pytest.fixture(scope="module")
def one_thread():
    """Tiny models run ~100x faster on one thread when the 2 cores are shared (OpenMP spin-waits)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)
