"""Training the learned predictor (the paper's recipe), run directories, resume, DDP, loading a trained run.

    loss = mean_{b,t,i} (yhat_{b,t+1,i} - y_{b,t+1,i})^2
    inputs z_0..z_{T-1} (B, T, d_in), targets y_1..y_T (B, T, m)
    AdamW(lr 3e-4, weight decay 0.01), grad-norm clip 1.0, batch 64, 10000 steps (TrainConfig defaults).

Data modes: num_source_systems = M > 0 draws M systems with one trajectory each once (on the training device)
and
samples batches from them with a seeded generator; M = 0 draws fresh systems every batch.

Run directory:
    config.json           RunConfig with model.input_dim/output_dim resolved (rebuilds the model)
    model.safetensors     model weights (latest checkpoint or final)
    checkpoint.safetensors  model + AdamW state + RNG states + step (mop.checkpoint), for resuming
    metrics.jsonl         {"step", "loss", "lr", "steps_per_s"} and {"step", "val_loss"} records
    tb/                   TensorBoard scalars
    done.json             written last; train() on a finished run with the same config returns at once

DDP: under `torchrun --nproc_per_node N` every rank draws the same global batch and trains on its slice
(rank r takes rows [r b, (r+1) b), b = batch_size / N); gradients are averaged by DistributedDataParallel,
so one step equals a single-process step on the global batch. Rank 0 writes the run directory.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import signal
import time
from pathlib import Path

import torch
import torch.distributed as dist
from torch import Tensor, nn

from mop.atomic import write_json
from mop.checkpoint import load_checkpoint, load_model_weights, save_checkpoint, save_model
from mop.config import ModelConfig, RunConfig, from_dict, to_dict
from mop.errors import MopError
from mop.model import build_model
from mop.systems import make_family

NUM_VAL_SYSTEMS = 256


def resolve_config(config: RunConfig) -> RunConfig:
    """Fill model.input_dim / output_dim (0 = from the system family): d_in = m + k, d_out = m."""
    family = make_family(config.system)
    d_in, m = family.output_dim + family.input_dim, family.output_dim
    model = config.model
    for name, value in (("input_dim", d_in), ("output_dim", m)):
        if getattr(model, name) not in (0, value):
            raise MopError(
                f"model.{name}={getattr(model, name)} does not match the "
                f"{config.system.family} family ({value}); leave it at 0"
            )
    return dataclasses.replace(config, model=dataclasses.replace(model, input_dim=d_in, output_dim=m))


def resolve_device(name: str) -> torch.device:
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise MopError(f"train.device={name!r} but CUDA is not available; use train.device=cpu")
    return torch.device(name)


# ----------------------------------------------------------------------------- data


class TrainingData:
    """Batches of (inputs (B, T, d_in), targets (B, T, m)) on `device`, all randomness from one generator."""

    def __init__(self, config: RunConfig, device: torch.device) -> None:
        self.family, self.cfg = make_family(config.system), config.train
        self.generator = torch.Generator(device=device).manual_seed(self.cfg.seed)
        self.inputs = self.targets = None
        if self.cfg.num_source_systems > 0:
            self.inputs, self.targets = self._draw(self.cfg.num_source_systems)  # (M, T, d_in), (M, T, m)

    def _draw(self, num_systems: int) -> tuple[Tensor, Tensor]:
        traj = self.family.generate(num_systems, self.cfg.horizon, generator=self.generator)
        z = traj.model_inputs()  # (B, T+1, d_in)
        return z[:, :-1].float().contiguous(), traj.y[:, 1:].float().contiguous()

    def batch(self) -> tuple[Tensor, Tensor]:
        if self.inputs is None:
            return self._draw(self.cfg.batch_size)
        index = torch.randint(
            0,
            self.inputs.shape[0],
            (self.cfg.batch_size,),
            generator=self.generator,
            device=self.generator.device,
        )
        return self.inputs[index], self.targets[index]


def validation_batch(config: RunConfig, device: torch.device) -> tuple[Tensor, Tensor]:
    """Held-out systems (a generator seeded apart from training) for the validation loss."""
    family = make_family(config.system)
    g = torch.Generator(device=device).manual_seed(config.train.seed + 1_000_003)
    traj = family.generate(NUM_VAL_SYSTEMS, config.train.horizon, generator=g)
    return traj.model_inputs()[:, :-1].float(), traj.y[:, 1:].float()


# ----------------------------------------------------------------------------- optimisation


def learning_rate(cfg, step: int) -> float:
    """Linear warm-up over warmup_steps, then constant or cosine decay to 0.1 lr."""
    if step < cfg.warmup_steps:
        return cfg.lr * (step + 1) / cfg.warmup_steps
    if cfg.lr_schedule == "constant":
        return cfg.lr
    frac = (step - cfg.warmup_steps) / max(1, cfg.steps - cfg.warmup_steps)
    return cfg.lr * (0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * frac)))


def make_optimizer(model: nn.Module, cfg, device: torch.device) -> torch.optim.Optimizer:
    """AdamW; weight decay on matrices only (nanoGPT), fused kernel on CUDA."""
    decay = [p for p in model.parameters() if p.dim() >= 2]
    no_decay = [p for p in model.parameters() if p.dim() < 2]
    groups = [{"params": decay, "weight_decay": cfg.weight_decay}, {"params": no_decay, "weight_decay": 0.0}]
    return torch.optim.AdamW(groups, lr=cfg.lr, betas=(0.9, 0.999), fused=device.type == "cuda")


def autocast(cfg, device: torch.device):
    """bf16 autocast on GPU with precision auto|bf16; fp32 otherwise."""
    use_bf16 = cfg.precision == "bf16" or (cfg.precision == "auto" and device.type == "cuda")
    if not use_bf16:
        return contextlib.nullcontext()
    return torch.autocast(device_type=device.type, dtype=torch.bfloat16)


COMPILE_MIN_STEPS_CPU = 500  # compiling takes ~1 min on 2 cores, then halves the paper step (mop bench train)


def maybe_compile(model: nn.Module, cfg, device: torch.device) -> nn.Module:
    """torch.compile for compile=on, and for auto on CUDA or on CPU runs long enough to repay compiling."""
    auto = device.type == "cuda" or cfg.steps >= COMPILE_MIN_STEPS_CPU
    if cfg.compile == "on" or (cfg.compile == "auto" and auto):
        return torch.compile(model)
    return model


def train_step(
    model: nn.Module,
    loss_fn,
    optimizer: torch.optim.Optimizer,
    inputs: Tensor,
    targets: Tensor,
    cfg,
    device: torch.device,
) -> Tensor:
    """One AdamW step on MSE over every position; returns the (detached) loss."""
    with autocast(cfg, device):
        loss = loss_fn(inputs, targets)
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip)
    optimizer.step()
    return loss.detach()


# ----------------------------------------------------------------------------- run directory


def _check_run_dir(out_dir: Path, config: RunConfig) -> bool:
    """True when `out_dir` holds a finished run of `config`; MopError when it holds a different config."""
    path = out_dir / "config.json"
    if not path.exists():
        return False
    try:
        saved = json.loads(path.read_text())
    except json.JSONDecodeError:
        raise MopError(f"{path} is not valid JSON; remove the run directory or use another --out") from None
    if saved != to_dict(config):
        diff = _diff(saved, to_dict(config))
        raise MopError(f"{out_dir} holds a run with a different config ({diff}); use another --out directory")
    return (out_dir / "done.json").exists()


def _diff(a: dict, b: dict, prefix: str = "") -> str:
    for key in sorted(set(a) | set(b)):
        x, y = a.get(key), b.get(key)
        if isinstance(x, dict) and isinstance(y, dict):
            found = _diff(x, y, f"{prefix}{key}.")
            if found:
                return found
        elif x != y:
            return f"{prefix}{key}: saved {x!r}, now {y!r}"
    return ""


class MetricsLog:
    """metrics.jsonl (JSON record a line) + TensorBoard scalars; resume drops records past the checkpoint."""

    def __init__(self, out_dir: Path, resume_step: int) -> None:
        from torch.utils.tensorboard import SummaryWriter

        self.path = out_dir / "metrics.jsonl"
        kept = []
        if self.path.exists():
            for line in self.path.read_text().splitlines():
                with contextlib.suppress(json.JSONDecodeError):
                    record = json.loads(line)
                    if record.get("step", 0) <= resume_step:
                        kept.append(line)
        from mop.atomic import write_text

        write_text(self.path, "".join(line + "\n" for line in kept))
        self.writer = SummaryWriter(str(out_dir / "tb"), purge_step=resume_step + 1 if resume_step else None)

    def log(self, record: dict) -> None:
        with open(self.path, "a") as handle:
            handle.write(json.dumps(record) + "\n")
        for key, value in record.items():
            if key != "step" and isinstance(value, float):
                tag = "val/loss" if key == "val_loss" else f"train/{key}"
                self.writer.add_scalar(tag, value, record["step"])

    def close(self) -> None:
        self.writer.close()


@contextlib.contextmanager
def stop_signals():
    """While active, SIGINT/SIGTERM set flag['stop'] instead of killing; the loop checkpoints and exits."""
    flag = {"stop": None}
    if not _main_thread():
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


def _main_thread() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()


# ----------------------------------------------------------------------------- the loop


def _rng_state(data: TrainingData, device: torch.device) -> dict[str, Tensor]:
    state = {"data": data.generator.get_state(), "torch": torch.get_rng_state()}
    if device.type == "cuda":
        state["cuda"] = torch.cuda.get_rng_state(device)
    return state


def _set_rng_state(data: TrainingData, state: dict[str, Tensor], device: torch.device) -> None:
    data.generator.set_state(state["data"])
    torch.set_rng_state(state["torch"])
    if device.type == "cuda" and "cuda" in state:
        torch.cuda.set_rng_state(state["cuda"], device)


def _distributed() -> tuple[int, int]:
    """(rank, world_size), initialising the process group under torchrun."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return 0, 1
    if not dist.is_initialized():
        nccl = torch.cuda.is_available() and os.environ.get("MOP_DDP_BACKEND") != "gloo"
        backend = "nccl" if nccl else "gloo"
        dist.init_process_group(backend)
    return dist.get_rank(), dist.get_world_size()


def train(config: RunConfig, out_dir: str | os.PathLike, *, progress: bool = True) -> Path:
    """Train `config` into `out_dir` (resuming from its checkpoint if any); returns the run directory."""
    out_dir = Path(out_dir)
    config = resolve_config(config)
    cfg = config.train
    rank, world = _distributed()
    if cfg.batch_size % world:
        raise MopError(
            f"train.batch_size ({cfg.batch_size}) must be divisible by the number of processes ({world})"
        )
    if _check_run_dir(out_dir, config):  # every rank reads it, so all return together
        return out_dir
    if cfg.deterministic:
        torch.use_deterministic_algorithms(True)
    device = resolve_device(cfg.device)
    if device.type == "cuda" and world > 1:
        device = torch.device("cuda", int(os.environ.get("LOCAL_RANK", "0")))
        torch.cuda.set_device(device)
    if device.type == "cuda":
        torch.backends.cuda.matmul.allow_tf32 = True
        torch.backends.cudnn.allow_tf32 = True
    if rank == 0:
        out_dir.mkdir(parents=True, exist_ok=True)
        write_json(out_dir / "config.json", to_dict(config))

    torch.manual_seed(cfg.seed)
    model = build_model(config.model).to(device)
    optimizer = make_optimizer(model, cfg, device)
    data = TrainingData(config, device)
    step = 0
    ckpt = out_dir / "checkpoint.safetensors"
    if ckpt.exists():
        step, rng, _ = load_checkpoint(ckpt, model, optimizer)
        _set_rng_state(data, rng, device)
    if world > 1:
        dist.barrier()
    loss_fn = maybe_compile(LossModule(model), cfg, device)
    if world > 1:
        loss_fn = nn.parallel.DistributedDataParallel(loss_fn)
    val = validation_batch(config, device) if rank == 0 else None
    log = MetricsLog(out_dir, step) if rank == 0 else None
    try:
        _loop(config, model, loss_fn, optimizer, data, val, log, step, out_dir, device, rank, world, progress)
    finally:
        if log is not None:
            log.close()
    return out_dir


class LossModule(nn.Module):
    """forward(inputs, targets) = model.loss(...): torch.compile and DDP hooks see the whole loss."""

    def __init__(self, model: nn.Module) -> None:
        super().__init__()
        self.model = model

    def forward(self, inputs: Tensor, targets: Tensor) -> Tensor:
        return self.model.loss(inputs, targets)


def _loop(
    config, model, loss_fn, optimizer, data, val, log, step, out_dir, device, rank, world, progress
) -> None:
    cfg = config.train
    model.train()
    bar = None
    if rank == 0 and progress:
        from tqdm import tqdm

        bar = tqdm(total=cfg.steps, initial=step, desc="train", dynamic_ncols=True)
    loss_sum = torch.zeros((), device=device)
    last_good, since, t0 = step, 0, time.perf_counter()
    with stop_signals() as flag:
        while step < cfg.steps:
            for group in optimizer.param_groups:
                group["lr"] = learning_rate(cfg, step)
            inputs, targets = data.batch()  # (B, T, d_in), (B, T, m): the global batch
            b = cfg.batch_size // world
            inputs, targets = inputs[rank * b : (rank + 1) * b], targets[rank * b : (rank + 1) * b]
            loss_sum += train_step(model, loss_fn, optimizer, inputs, targets, cfg, device)
            step, since = step + 1, since + 1
            if bar is not None:
                bar.update(1)
            at_log = step % cfg.log_every == 0 or step == cfg.steps
            at_ckpt = step % cfg.checkpoint_every == 0 or step == cfg.steps or flag["stop"]
            if not (at_log or at_ckpt):
                continue
            mean_loss = float(loss_sum) / since
            if not math.isfinite(mean_loss):
                raise MopError(
                    f"training loss became {mean_loss} between steps {step - since} and {step}; "
                    f"the last good checkpoint (step {last_good}) is kept in {out_dir}; "
                    f"try a lower train.lr"
                )
            if rank == 0 and at_log:
                rate = since / (time.perf_counter() - t0)
                record = {
                    "step": step,
                    "loss": mean_loss,
                    "lr": learning_rate(cfg, step - 1),
                    "steps_per_s": rate,
                }
                log.log(record)
                if bar is not None:
                    bar.set_postfix(loss=f"{mean_loss:.4g}", steps_per_s=f"{rate:.1f}")
            loss_sum.zero_()
            since, t0 = 0, time.perf_counter()
            if at_ckpt:
                if rank == 0:
                    if step % (cfg.checkpoint_every) == 0 or step == cfg.steps:
                        log.log({"step": step, "val_loss": validation_loss(model, val, cfg, device)})
                    save_checkpoint(
                        out_dir / "checkpoint.safetensors", step, model, optimizer, _rng_state(data, device)
                    )
                    save_model(out_dir / "model.safetensors", model)
                last_good = step
                if world > 1:
                    dist.barrier()
            if flag["stop"]:
                raise MopError(
                    f"stopped by {flag['stop']} at step {step}; checkpoint saved in {out_dir}, "
                    f"run the same command to resume"
                )
    if bar is not None:
        bar.close()
    if rank == 0:
        write_json(out_dir / "done.json", {"step": step})


@torch.no_grad()
def validation_loss(model: nn.Module, val: tuple[Tensor, Tensor], cfg, device: torch.device) -> float:
    """Mean model.loss on the held-out systems (does not touch any RNG)."""
    model.eval()
    with autocast(cfg, device):
        loss = float(model.loss(*val))
    model.train()
    return loss


# ----------------------------------------------------------------------------- loading


def load_config(run_dir: str | os.PathLike) -> RunConfig:
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise MopError(f"run directory {run_dir} does not exist; train one with `mop train --out {run_dir}`")
    path = run_dir / "config.json"
    if not path.is_file():
        raise MopError(f"{run_dir} has no config.json; it is not a mop run directory")
    try:
        return from_dict(RunConfig, json.loads(path.read_text()))
    except json.JSONDecodeError:
        raise MopError(f"{path} is not valid JSON; the run directory is damaged") from None


def load_model(
    run_dir: str | os.PathLike, device: str | torch.device = "cpu"
) -> tuple[nn.Module, ModelConfig]:
    """The model of a run directory (config.json + model.safetensors), in eval mode on `device`."""
    config = load_config(run_dir)
    model = build_model(config.model)
    load_model_weights(Path(run_dir) / "model.safetensors", model)
    return model.to(device).eval(), config.model


def load_predictor(run_dir: str | os.PathLike, device: str | torch.device = "cpu", mode: str = "window"):
    """A trained run as a LearnedPredictor (the Predictor interface of the classical filters)."""
    from mop.learned import LearnedPredictor

    model, _ = load_model(run_dir, device)
    return LearnedPredictor(model, name="mop", mode=mode)
