"""One optimisation step of the paper's recipe, and the settings around it (schedule, precision, compile):

loss = model.loss(inputs, targets)   (MSE, or Gaussian NLL for readout 'gaussian')
AdamW(lr 3e-4, weight decay 0.01 on matrices), grad-norm clip 1.0, linear warm-up, constant or cosine
(TrainConfig defaults).
"""

from __future__ import annotations

import contextlib
import math

import torch
from torch import Tensor, nn

from mop.config import TrainConfig


def learning_rate(cfg: TrainConfig, step: int) -> float:
    """Linear warm-up over warmup_steps, then constant or cosine decay to 0.1 lr."""
    if step < cfg.warmup_steps:
        return cfg.lr * (step + 1) / cfg.warmup_steps
    if cfg.lr_schedule == "constant":
        return cfg.lr
    frac = (step - cfg.warmup_steps) / max(1, cfg.steps - cfg.warmup_steps)
    return cfg.lr * (0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * frac)))


def make_optimizer(model: nn.Module, cfg: TrainConfig, device: torch.device) -> torch.optim.Optimizer:
    """AdamW; weight decay on matrices only (nanoGPT), fused kernel on CUDA."""
    decay = [p for p in model.parameters() if p.dim() >= 2]
    no_decay = [p for p in model.parameters() if p.dim() < 2]
    groups = [{"params": decay, "weight_decay": cfg.weight_decay}, {"params": no_decay, "weight_decay": 0.0}]
    return torch.optim.AdamW(groups, lr=cfg.lr, betas=(0.9, 0.999), fused=device.type == "cuda")


def autocast(cfg: TrainConfig, device: torch.device):
    """bf16 autocast on GPU with precision auto|bf16; fp32 otherwise."""
    use_bf16 = cfg.precision == "bf16" or (cfg.precision == "auto" and device.type == "cuda")
    if not use_bf16:
        return contextlib.nullcontext()
    return torch.autocast(device_type=device.type, dtype=torch.bfloat16)


COMPILE_MIN_STEPS_CPU = 500  # compiling takes ~1 min on 2 cores, then halves the paper step (mop bench train)


def maybe_compile(model: nn.Module, cfg: TrainConfig, device: torch.device) -> nn.Module:
    """torch.compile for compile=on, and for auto on CUDA or on CPU runs long enough to repay compiling.
    compile=graphs: mode "reduce-overhead", which on CUDA replays the compiled loss and its backward as CUDA
    graphs (one launch instead of hundreds: the paper's step is launch-bound on a GPU, docs/results/paper.md);
    elsewhere the same as on."""
    if cfg.compile == "graphs":
        return torch.compile(model, mode="reduce-overhead")
    auto = device.type == "cuda" or cfg.steps >= COMPILE_MIN_STEPS_CPU
    if cfg.compile == "on" or (cfg.compile == "auto" and auto):
        return torch.compile(model)
    return model


class LossModule(nn.Module):
    """forward(inputs, targets[, fitted]) = model.loss(...): torch.compile and DDP see the whole loss."""

    def __init__(self, model: nn.Module) -> None:
        super().__init__()
        self.model = model

    def forward(self, inputs: Tensor, targets: Tensor, *fitted: Tensor) -> Tensor:
        return self.model.loss(inputs, targets, *fitted)


def train_step(
    model: nn.Module,
    loss_fn,
    optimizer: torch.optim.Optimizer,
    inputs: Tensor,
    targets: Tensor,
    cfg: TrainConfig,
    device: torch.device,
    fitted: Tensor | None = None,
) -> Tensor:
    """One AdamW step, loss over all positions of inputs (B, T, d_in), targets (B, T, m); detached loss.
    fitted (B, d, m)|None: each record's feature coefficients (train.context_prefix, mop.train.context)."""
    if cfg.compile == "graphs":  # a new iteration: the CUDA graphs may reuse the last step's buffers
        torch.compiler.cudagraph_mark_step_begin()
    with autocast(cfg, device):
        loss = loss_fn(inputs, targets) if fitted is None else loss_fn(inputs, targets, fitted)
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip)
    optimizer.step()
    return loss.detach()


@torch.no_grad()
def validation_loss(
    model: nn.Module, val: tuple[Tensor, ...], cfg: TrainConfig, device: torch.device
) -> float:
    """Mean model.loss on the held-out systems (inputs, targets[, fitted]; does not touch any RNG)."""
    model.eval()
    with autocast(cfg, device):
        loss = float(model.loss(*val))
    model.train()
    return loss
