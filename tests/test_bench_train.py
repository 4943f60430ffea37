"""`mop bench train`: the phase-by-phase step it times is mop's training step, and compile=graphs trains as
compile=off does (on a CPU, mode reduce-overhead is plain inductor; CUDA graphs need a GPU)."""

from __future__ import annotations

import dataclasses

import torch

from mop import train as mt
from mop.bench.train import PHASES, phased_training
from mop.config import ModelConfig, RunConfig, TrainConfig
from mop.models import build_model

CPU = torch.device("cpu")


def _config(**train) -> RunConfig:
    model = ModelConfig(num_layers=1, num_heads=2, width=16)
    base = TrainConfig(batch_size=8, num_source_systems=32, horizon=12, compile="off", device="cpu")
    return RunConfig(model=model, train=dataclasses.replace(base, **train))


def _train_steps(config: RunConfig, steps: int) -> torch.nn.Module:
    """What mop_step in mop.bench.train (and the training loop) runs: mop.train.train_step."""
    config = mt.resolve_config(config)
    torch.manual_seed(0)
    model = build_model(config.model).train()
    optimizer = mt.make_optimizer(model, config.train, CPU)
    loss_fn = mt.maybe_compile(mt.LossModule(model), config.train, CPU)
    data = mt.TrainingData(config, CPU)
    for _ in range(steps):
        mt.train_step(model, loss_fn, optimizer, *data.batch(), config.train, CPU)
    return model


def test_phased_step_makes_the_same_updates_as_train_step():
    config = _config()
    phases, phased = phased_training(config, CPU, warmup=1, steps=2)
    assert tuple(phases) == PHASES and all(ms >= 0 for ms in phases.values())
    reference = _train_steps(config, 3)
    for (name, a), b in zip(phased.state_dict().items(), reference.state_dict().values(), strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0, msg=name)


def test_compile_graphs_trains_as_uncompiled():
    plain = _train_steps(_config(), 3)
    graphs = _train_steps(_config(compile="graphs"), 3)
    for (name, a), b in zip(plain.state_dict().items(), graphs.state_dict().values(), strict=True):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5, msg=name)
