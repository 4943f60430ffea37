"""What a training will cost, said before its first step: the model's size, the steps and an estimated time.

The time comes from AdamW steps of a copy of the model on random batches of the run's shape, on the run's
device: WARMUP_STEPS untimed (the first steps allocate and pick kernels), then each of at least
MIN_TRIAL_STEPS and at most TRIAL_STEPS steps timed alone, until TRIAL_SECONDS have passed; the estimate is
their median, so one step slowed by other work (or a collection) does not multiply the whole estimate (two
steps after one warm-up estimated 14 min for a run that took 2 min 31 s). The run's own model,
optimizer, data generator and torch's global random state are left untouched, so the training is the same
with or without the estimate.
"""

from __future__ import annotations

import copy
import statistics
import time

import torch

from mop.config import RunConfig
from mop.train.auto import describe_features
from mop.train.optim import LossModule, make_optimizer, train_step

WARMUP_STEPS = 2
MIN_TRIAL_STEPS = 3
TRIAL_STEPS = 30
TRIAL_SECONDS = 1.5


def step_seconds(
    config: RunConfig, model: torch.nn.Module, device: torch.device, steps: int = TRIAL_STEPS
) -> float:
    """Median wall-clock seconds of one training step of `config` over at most `steps` timed steps
    (uncompiled; see the module docstring)."""
    cfg = config.train
    trial = copy.deepcopy(model).to(device)
    optimizer = make_optimizer(trial, cfg, device)
    loss_fn = LossModule(trial)
    g = torch.Generator(device=device).manual_seed(0)
    shape = (cfg.batch_size, cfg.horizon)
    inputs = torch.randn(*shape, config.model.input_dim, generator=g, device=device)
    targets = torch.randn(*shape, config.model.output_dim, generator=g, device=device)
    sync = torch.cuda.synchronize if device.type == "cuda" else lambda _device: None
    times: list[float] = []
    with torch.random.fork_rng(devices=[device] if device.type == "cuda" else []):
        for _ in range(WARMUP_STEPS):  # untimed
            train_step(trial, loss_fn, optimizer, inputs, targets, cfg, device)
        sync(device)
        while len(times) < max(1, min(steps, MIN_TRIAL_STEPS)) or (
            len(times) < steps and sum(times) < TRIAL_SECONDS
        ):
            start = time.perf_counter()
            train_step(trial, loss_fn, optimizer, inputs, targets, cfg, device)
            sync(device)
            times.append(time.perf_counter() - start)
    return statistics.median(times)


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
        f"({1000 * seconds:.0f} ms per step: the median of up to {TRIAL_STEPS} trial steps after "
        f"{WARMUP_STEPS} untimed, under the present load; other work on the machine changes it)"
    )
