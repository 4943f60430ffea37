"""What a training will cost, said before its first step: the model's size, the steps and an estimated time.

The time comes from TRIAL_STEPS AdamW steps of a copy of the model on random batches of the run's shape, on
the run's device, timed after one untimed warm-up step: the run's own model, optimizer, data generator and
torch's global random state are left untouched, so the training is the same with or without the estimate.
"""

from __future__ import annotations

import copy
import time

import torch

from mop.config import RunConfig
from mop.train.auto import describe_features
from mop.train.optim import LossModule, make_optimizer, train_step

TRIAL_STEPS = 2


def step_seconds(
    config: RunConfig, model: torch.nn.Module, device: torch.device, steps: int = TRIAL_STEPS
) -> float:
    """Mean wall-clock seconds of one training step of `config` (uncompiled; see the module docstring)."""
    cfg = config.train
    trial = copy.deepcopy(model).to(device)
    optimizer = make_optimizer(trial, cfg, device)
    loss_fn = LossModule(trial)
    g = torch.Generator(device=device).manual_seed(0)
    shape = (cfg.batch_size, cfg.horizon)
    inputs = torch.randn(*shape, config.model.input_dim, generator=g, device=device)
    targets = torch.randn(*shape, config.model.output_dim, generator=g, device=device)
    with torch.random.fork_rng(devices=[device] if device.type == "cuda" else []):
        train_step(trial, loss_fn, optimizer, inputs, targets, cfg, device)  # warm-up, untimed
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        start = time.perf_counter()
        for _ in range(steps):
            train_step(trial, loss_fn, optimizer, inputs, targets, cfg, device)
        if device.type == "cuda":
            torch.cuda.synchronize(device)
    return (time.perf_counter() - start) / steps


def duration(seconds: float) -> str:
    """'2 h 05 min', '3 min 20 s' or '40 s'."""
    seconds = int(round(seconds))
    if seconds >= 3600:
        return f"{seconds // 3600} h {seconds % 3600 // 60:02d} min"
    if seconds >= 60:
        return f"{seconds // 60} min {seconds % 60:02d} s"
    return f"{seconds} s"


def plan_line(config: RunConfig, model: torch.nn.Module, device: torch.device, start_step: int = 0) -> str:
    """One line: parameters, layers x width, the input features, steps left of batch x horizon, and the
    estimated time."""
    m, t = config.model, config.train
    params = sum(p.numel() for p in model.parameters())
    left = max(t.steps - start_step, 0)
    seconds = step_seconds(config, model, device) if left else 0.0
    features = describe_features(m)  # what model.features=auto chose, or the keys as given
    shape = f"{m.arch} {m.num_layers} x {m.width}" + ("" if features == "none" else f", features {features}")
    resumed = f"resuming at step {start_step} of {t.steps} from the run's checkpoint; " if start_step else ""
    return (
        f"model: {params:,} parameters ({shape}); {resumed}{left} steps of batch "
        f"{t.batch_size} x {t.horizon} on {device.type}: roughly {duration(seconds * left)} "
        f"({1000 * seconds:.0f} ms per step, timed on {TRIAL_STEPS} trial steps under the present load; "
        "other work on the machine changes it)"
    )
