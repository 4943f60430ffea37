"""The training loop: train(config, out_dir) runs (or resumes) a run directory (mop.train.rundir).

Every checkpoint_every steps (and at the end) rank 0 logs the validation loss and writes the whole training
state, so a run stopped anywhere resumes to the same weights as one never stopped (bit for bit on CPU).
SIGINT/SIGTERM checkpoint and stop (run the same command to resume); a non-finite loss stops with the last
good checkpoint kept. A deadline (a time of `clock()`: `mop train --max-minutes`) checkpoints and stops
cleanly after the step that reaches it, with a line saying where; the run resumes from there as from a
signal, to the same weights as one never stopped.

DDP: under `torchrun --nproc_per_node N` every rank draws the same global batch and trains on its slice
(rank r takes rows [r b, (r+1) b), b = batch_size / N); gradients are averaged by DistributedDataParallel,
so one step equals a single-process step on the global batch. Rank 0 writes the run directory.

The loop is a plain trainer: a recipe that adds steps around it (the fine-tune's source weights at step 0,
the correction's gain after the last step: mop.recipe.training) hands them in as TrainHooks.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import signal
import threading
import time
from collections.abc import Callable
from pathlib import Path

import torch
import torch.distributed as dist
from torch import Tensor, nn

from mop.atomic import clean_orphans
from mop.checkpoint import load_model_weights, save_model
from mop.config import RunConfig
from mop.errors import MopError
from mop.models import build_model
from mop.progress import progress as make_progress
from mop.runs import load_model
from mop.train.data import TrainingData, validation_batch
from mop.train.device import init_distributed, setup_device
from mop.train.estimate import duration, plan_line
from mop.train.lock import run_lock
from mop.train.optim import (
    LossModule,
    learning_rate,
    make_optimizer,
    maybe_compile,
    train_step,
    validation_loss,
)
from mop.train.records import TrainingRecords
from mop.train.rollout_loss import RolloutLoss, check_rollout, rollout_start
from mop.train.rundir import (
    MetricsLog,
    check_run_dir,
    fresh_start,
    resolve_config,
    restore_training_state,
    save_training_state,
    write_config,
    write_done,
    write_input_stats,
)


@dataclasses.dataclass(frozen=True)
class TrainHooks:
    """Steps a recipe runs around the loop, each handed the resolved config (mop.train.rundir.resolve_config).

    check(config): before the run directory is read or written (one-line MopErrors);
    initial_weights(config, model): at step 0 of a run that starts (not a resumed one), in place, before
        the optimizer's first step;
    after(config, model, out_dir): rank 0, after the last step (and after train.keep_best has loaded the
        kept weights), before done.json; also on a resumed run stopped between the two, so it must be safe
        to run twice.
    """

    check: Callable[[RunConfig], None] | None = None
    initial_weights: Callable[[RunConfig, nn.Module], None] | None = None
    after: Callable[[RunConfig, nn.Module, Path], None] | None = None


def clock() -> float:
    """The loop's clock (seconds, monotonic) for deadlines: `train(..., deadline=clock() + seconds)`."""
    return time.monotonic()


# config keys whose meaning is a recipe's step: a config naming one trains with that recipe's TrainHooks
RECIPE_KEYS = ("init", "shrink_correction")


@dataclasses.dataclass
class TrainState:
    """What the loop reads and advances; rank 0 alone holds the validation batch and the metrics log."""

    config: RunConfig
    out_dir: Path
    device: torch.device
    model: nn.Module
    loss_fn: nn.Module  # LossModule(model), maybe compiled, DDP-wrapped under torchrun
    optimizer: torch.optim.Optimizer
    data: TrainingData
    step: int = 0
    rank: int = 0
    world: int = 1
    val: tuple[Tensor, Tensor] | None = None  # (N, T, d_in), (N, T, m)
    log: MetricsLog | None = None
    best: tuple[int, float] | None = None  # train.keep_best: (step, val_loss) of model.safetensors' weights
    hooks: TrainHooks = TrainHooks()
    rollout_fn: nn.Module | None = None  # train.rollout_after: the simulation loss (mop.train.rollout_loss)


def train(
    config: RunConfig,
    out_dir: str | os.PathLike,
    *,
    progress: bool = True,
    wait: bool = True,
    fresh: bool = False,
    announce: Callable[[str], None] | None = None,
    hooks: TrainHooks | None = None,
    records: TrainingRecords | None = None,
    deadline: float | None = None,
) -> Path:
    """Train `config` into `out_dir` (resuming from its checkpoint if any); returns the run directory.

    Rank 0 holds the run directory's lock (mop.train.lock) while training: another process training the
    same directory is waited for (wait=True; then its finished run is reused) or refused in one line.
    fresh: start over, removing what the directory holds besides config.json (a damaged run).
    announce: given, rank 0 hands it one line before the first step: the model's size, the steps left and an
    estimated time (mop.train.estimate.plan_line; a few trial steps on a copy of the model).
    hooks: a recipe's steps around the loop (TrainHooks); a config naming train.init or
    train.shrink_correction is refused without them (mop.recipe.training.train hands them in).
    records: config.data's records in memory (mop.train.records.TrainingRecords), read once by the caller;
    None reads data.path.
    deadline: a time of clock() (not part of the config): the first step that ends at or after it
    checkpoints and stops the run unfinished (no done.json, no `after` hook), announcing the step it reached
    and how to resume; running it again resumes it to the weights of a run never stopped.
    Temporaries of writes killed in an earlier run are removed first.
    """
    _train(config, Path(out_dir), progress, wait, fresh, announce, hooks, records, deadline)
    return Path(out_dir)


def train_model(
    config: RunConfig,
    out_dir: str | os.PathLike,
    *,
    progress: bool = True,
    wait: bool = True,
    hooks: TrainHooks | None = None,
) -> nn.Module:
    """Train like train() and hand back the trained model, in eval mode on the CPU, so a caller predicts
    with it without reloading it; a run `out_dir` already finished is loaded from there (mop.runs)."""
    model = _train(config, Path(out_dir), progress, wait, False, None, hooks)
    return load_model(out_dir)[0] if model is None else model.to("cpu").eval()


def _train(
    config: RunConfig,
    out_dir: Path,
    progress: bool,
    wait: bool,
    fresh: bool,
    announce: Callable[[str], None] | None = None,
    hooks: TrainHooks | None = None,
    records: TrainingRecords | None = None,
    deadline: float | None = None,
) -> nn.Module | None:
    """The trained model, or None when `out_dir` holds a finished run of `config` (nothing is trained)."""
    if config.data is not None and records is None:  # a config naming its data: read once, here
        records = TrainingRecords.read(config.data.path, config.data.validation_path or None)
    config = resolve_config(config, records)
    if hooks is None:
        _check_no_recipe_keys(config)
        hooks = TrainHooks()
    if hooks.check is not None:
        hooks.check(config)
    cfg = config.train
    rank, world = init_distributed()
    if cfg.batch_size % world:
        raise MopError(
            f"train.batch_size ({cfg.batch_size}) must be divisible by the number of processes ({world})"
        )
    if check_run_dir(out_dir, config) and not fresh:  # every rank reads it, so all return together
        return None
    with run_lock(out_dir, wait) if rank == 0 else contextlib.nullcontext():
        if check_run_dir(out_dir, config) and not fresh:  # finished by the process we waited for
            return None
        if rank == 0:
            clean_orphans(out_dir)
            if fresh:
                fresh_start(out_dir)
        return _train_locked(config, out_dir, rank, world, progress, announce, hooks, records, deadline)


def _check_no_recipe_keys(config: RunConfig) -> None:
    """One-line MopError for a config naming a recipe's key (RECIPE_KEYS) trained without its steps."""
    for key in RECIPE_KEYS:
        if getattr(config.train, key):
            raise MopError(
                f"train.{key} is a step of the fine-tune recipe, which this trainer was not given: train "
                "the config with mop.recipe.training.train (as `mop train` does)"
            )


def _train_locked(
    config: RunConfig,
    out_dir: Path,
    rank: int,
    world: int,
    progress: bool,
    announce: Callable[[str], None] | None,
    hooks: TrainHooks,
    records: TrainingRecords | None = None,
    deadline: float | None = None,
) -> nn.Module:
    device = setup_device(config.train, world)
    with torch.device("meta"):  # a model that refuses its config says so before the run folder is written
        build_model(config.model)
    if rank == 0:
        write_config(out_dir, config)
    state = _start(config, out_dir, device, rank, world, hooks, records)
    if announce is not None and rank == 0:
        announce(plan_line(config, state.model, device, state.step))
    try:
        _loop(state, progress, deadline, announce)
    finally:
        if state.log is not None:
            state.log.close()
    return state.model


def _start(
    config: RunConfig,
    out_dir: Path,
    device: torch.device,
    rank: int,
    world: int,
    hooks: TrainHooks,
    records: TrainingRecords | None = None,
) -> TrainState:
    """Seeded model, AdamW and data, restored from the checkpoint when there is one (else the recipe's
    initial weights, where it has them)."""
    torch.manual_seed(config.train.seed)
    model = build_model(config.model).to(device)
    optimizer = make_optimizer(model, config.train, device)
    data = TrainingData(config, device, records)
    step = restore_training_state(out_dir, model, optimizer, data.generator, device)
    if step == 0 and hooks.initial_weights is not None:
        hooks.initial_weights(config, model)
    if world > 1:
        dist.barrier()
    loss_fn = maybe_compile(LossModule(model), config.train, device)
    check_rollout(config)
    rollout_fn = RolloutLoss(model, config.train.rollout_after) if config.train.rollout_after else None
    if world > 1:
        loss_fn = nn.parallel.DistributedDataParallel(loss_fn)
        rollout_fn = rollout_fn and nn.parallel.DistributedDataParallel(rollout_fn)
    state = TrainState(
        config, out_dir, device, model, loss_fn, optimizer, data, step, rank, world, hooks=hooks
    )
    state.rollout_fn = rollout_fn
    if rank == 0:
        state.val = validation_batch(config, device, records)
        write_input_stats(out_dir, state.val[0])
        state.log = MetricsLog(out_dir, step)
        if config.train.keep_best:
            state.best = state.log.best_val()  # resumed: the best before the checkpoint (metrics kept to it)
            if state.best is None:  # step 0: the model as it starts is the first candidate
                _validate(state)
    return state


def _loop(
    state: TrainState,
    progress: bool,
    deadline: float | None = None,
    announce: Callable[[str], None] | None = None,
) -> None:
    cfg = state.config.train
    began, started = clock(), state.step
    state.model.train()
    bar = make_progress(cfg.steps, "train", initial=state.step, disable=not (state.rank == 0 and progress))
    loss_sum = torch.zeros((), device=state.device)
    last_good, since, t0 = state.step, 0, time.perf_counter()
    with stop_signals() as flag:
        while state.step < cfg.steps:
            loss_sum += _step(state)
            state.step, since = state.step + 1, since + 1
            bar.update(1)
            timed_out = deadline is not None and state.step < cfg.steps and _past(deadline, state)
            # a stop on time logs its step too: the run says how far it trained (mop.runs.warn_if_unfinished)
            at_log = state.step % cfg.log_every == 0 or state.step == cfg.steps or timed_out
            at_ckpt = (
                state.step % cfg.checkpoint_every == 0 or state.step == cfg.steps or flag["stop"] or timed_out
            )
            if not (at_log or at_ckpt):
                continue
            mean_loss = float(loss_sum) / since
            if not math.isfinite(mean_loss):
                raise MopError(_diverged(state, mean_loss, since, last_good))
            if state.rank == 0 and at_log:
                rate = since / (time.perf_counter() - t0)
                record = {"step": state.step, "loss": mean_loss, "lr": learning_rate(cfg, state.step - 1)}
                state.log.log({**record, "steps_per_s": rate})
                bar.set_postfix(loss=f"{mean_loss:.4g}", steps_per_s=f"{rate:.1f}")
            loss_sum.zero_()
            since, t0 = 0, time.perf_counter()
            if at_ckpt:
                _checkpoint(state)
                last_good = state.step
            if timed_out and not flag["stop"]:
                bar.close()
                if announce is not None and state.rank == 0:
                    announce(_timed_out(state, clock() - began, started))
                return
            if flag["stop"]:
                raise MopError(
                    f"stopped by {flag['stop']} at step {state.step}; checkpoint saved in {state.out_dir}, "
                    f"run the same command to resume"
                )
    bar.close()
    if state.best is not None:  # the caller gets the kept weights
        load_model_weights(state.out_dir / "model.safetensors", state.model)
    if state.rank == 0 and state.hooks.after is not None:
        state.hooks.after(state.config, state.model, state.out_dir)
    if state.rank == 0:
        write_done(state.out_dir, state.step, None if state.best is None else state.best[0])


def _past(deadline: float, state: TrainState) -> bool:
    """Whether clock() has reached `deadline`; under torchrun rank 0's clock decides for every rank."""
    past = clock() >= deadline
    if state.world > 1:
        flag = torch.tensor([float(past)], device=state.device)
        dist.broadcast(flag, src=0)
        past = bool(flag.item())
    return past


def _timed_out(state: TrainState, seconds: float, started: int) -> str:
    """The line of a run stopped by its deadline: the step it reached, the time, how to resume."""
    cfg = state.config.train
    weights = "the lowest validation loss's weights so far" if cfg.keep_best else "the weights of that step"
    return (
        f"time limit: stopped at step {state.step} of {cfg.steps} ({state.step - started} steps in "
        f"{duration(seconds)}); the checkpoint is saved in {state.out_dir}: run the same command to resume "
        f"from step {state.step} (with or without a time limit). Meanwhile the run predicts with "
        f"{weights} (mop.load and `mop predict` warn that it is unfinished)"
    )


def _diverged(state: TrainState, loss: float, since: int, last_good: int) -> str:
    """The message of a non-finite loss: where it happened, which checkpoint is kept (if any), what to do."""
    where = f"training loss became {loss} between steps {state.step - since} and {state.step}"
    lr = f"try a lower train.lr (it is {state.config.train.lr:g})"
    if last_good == 0:
        return f"{where}, before the first checkpoint, so no weights were saved in {state.out_dir}; {lr}"
    return f"{where}; the last good checkpoint (step {last_good}) is kept in {state.out_dir}; {lr}"


def _step(state: TrainState) -> Tensor:
    """Set the scheduled lr, draw the global batch, train on this rank's slice; the detached loss."""
    cfg = state.config.train
    for group in state.optimizer.param_groups:
        group["lr"] = learning_rate(cfg, state.step)
    batch = state.data.batch()  # (B, T, d_in), (B, T, m)[, fitted (B, d, m)]: the global batch
    b, r = cfg.batch_size // state.world, state.rank
    inputs, targets, *fitted = (a[r * b : (r + 1) * b] for a in batch)
    start = rollout_start(state.config)
    loss_fn = state.rollout_fn if start is not None and state.step >= start else state.loss_fn
    return train_step(state.model, loss_fn, state.optimizer, inputs, targets, cfg, state.device, *fitted)


def _checkpoint(state: TrainState) -> None:
    """Rank 0: validation loss at scheduled checkpoints, then the whole training state; all ranks wait."""
    cfg = state.config.train
    if state.rank == 0:
        if state.step % cfg.checkpoint_every == 0 or state.step == cfg.steps:
            _validate(state)
        save_training_state(
            state.out_dir,
            state.step,
            state.model,
            state.optimizer,
            state.data.generator,
            state.device,
            with_model=not cfg.keep_best,
        )
    if state.world > 1:
        dist.barrier()


def _validate(state: TrainState) -> None:
    """Rank 0: log the validation loss; with train.keep_best write model.safetensors when it is the lowest
    so far (before the checkpoint, so a resume from an earlier checkpoint recomputes the same choice)."""
    val_loss = validation_loss(state.model, state.val, state.config.train, state.device)
    state.log.log({"step": state.step, "val_loss": val_loss})
    if state.config.train.keep_best and (state.best is None or val_loss < state.best[1]):
        save_model(state.out_dir / "model.safetensors", state.model)
        state.best = (state.step, val_loss)


@contextlib.contextmanager
def stop_signals():
    """While active, SIGINT/SIGTERM set flag['stop'] instead of killing; the loop checkpoints and exits."""
    flag = {"stop": None}
    if threading.current_thread() is not threading.main_thread():
        yield flag
        return
    old = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}

    def handler(signum, frame):
        flag["stop"] = signal.Signals(signum).name

    for s in old:
        signal.signal(s, handler)
    try:
        yield flag
    finally:
        for s, h in old.items():
            signal.signal(s, h)
