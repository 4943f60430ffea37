"""`mop bench train`: milliseconds per training step, mop's trainer vs a plain Hugging Face GPT-2 loop.

Both train the paper's configuration (12 layers, 8 heads, width 256, batch 64, T = 50, linear family d = 5)
with AdamW(3e-4, weight decay 0.01), grad-norm clip 1.0 and MSE, in the same process, one after the other:
- mop: mop.train.train_step with its device settings (bf16 autocast, fused AdamW, torch.compile on CUDA;
  fp32 on CPU), batches drawn from source systems held on the device.
- hf_gpt2: transformers.GPT2Model(inputs_embeds=...) in fp32 with linear read-in / read-out around it and
  a plain PyTorch loop, as the authors' code does.
Warm-up steps (and compilation) are excluded from the timing.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time

import torch
from torch import nn

from mop import train as mt
from mop.config import ModelConfig, RunConfig, TrainConfig
from mop.errors import require
from mop.models import build_model
from mop.train import resolve_device


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--device", default=None, help="cpu or cuda (default: cuda if available)")
    parser.add_argument("--steps", type=int, default=None, help="timed steps (cpu 5, cuda 100)")
    parser.add_argument("--warmup", type=int, default=None, help="untimed warm-up steps (cpu 2, cuda 20)")
    parser.add_argument("--layers", type=int, default=12, help="transformer layers (12)")
    parser.add_argument("--width", type=int, default=256, help="model width (256)")
    parser.add_argument("--heads", type=int, default=8, help="attention heads (8)")
    parser.add_argument("--batch-size", type=int, default=64, help="batch size (64)")
    parser.add_argument(
        "--compile",
        choices=("auto", "on", "off", "graphs"),
        default="auto",
        help="torch.compile for mop (auto: on for CUDA; graphs: on, with CUDA graphs)",
    )
    parser.add_argument(
        "--precision",
        choices=("auto", "fp32", "bf16"),
        default="auto",
        help="mop's autocast (auto: bf16 on CUDA, fp32 on CPU); the HF loop stays fp32 as the authors ran it",
    )
    parser.add_argument("--skip-hf", action="store_true", help="time mop only")
    parser.add_argument(
        "--phases",
        action="store_true",
        help="also time mop's step phase by phase (batch, forward, backward, clip, optimizer), the device "
        "synchronised after each: where a launch-bound step spends its time",
    )


def _time(step, device: torch.device, warmup: int, steps: int) -> float:
    """Mean milliseconds of step() over `steps` calls after `warmup` calls."""
    for _ in range(warmup):
        step()
    _sync(device)
    start = time.perf_counter()
    for _ in range(steps):
        step()
    _sync(device)
    return 1000 * (time.perf_counter() - start) / steps


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _mop_parts(config: RunConfig, device: torch.device):
    """(resolved config, model, optimizer, loss_fn, data) of mop's trainer, seeded as every run here."""
    config = mt.resolve_config(config)
    torch.manual_seed(0)
    model = build_model(config.model).to(device).train()
    optimizer = mt.make_optimizer(model, config.train, device)
    loss_fn = mt.maybe_compile(mt.LossModule(model), config.train, device)
    return config, model, optimizer, loss_fn, mt.TrainingData(config, device)


def mop_step(config: RunConfig, device: torch.device):
    config, model, optimizer, loss_fn, data = _mop_parts(config, device)
    return lambda: mt.train_step(model, loss_fn, optimizer, *data.batch(), config.train, device)


PHASES = ("batch", "forward", "backward", "clip", "optimizer")


def mop_phases(config: RunConfig, device: torch.device, warmup: int, steps: int) -> dict[str, float]:
    """Mean milliseconds of each phase of mop's training step (PHASES), the device synchronised after each
    phase, so phases do not overlap as they do in an unsynchronised step: their sum is at least the step."""
    return phased_training(config, device, warmup, steps)[0]


def phased_training(
    config: RunConfig, device: torch.device, warmup: int, steps: int
) -> tuple[dict[str, float], nn.Module]:
    """warmup + steps steps of mop.train.train_step taken phase by phase: (mean ms per phase over the last
    `steps`, the trained model). The same updates as train_step (tests/test_bench_train.py)."""
    config, model, optimizer, loss_fn, data = _mop_parts(config, device)
    cfg = config.train
    totals = dict.fromkeys(PHASES, 0.0)

    def timed(name: str, fn, count: bool):
        start = time.perf_counter()
        out = fn()
        _sync(device)
        if count:
            totals[name] += time.perf_counter() - start
        return out

    for i in range(warmup + steps):
        count = i >= warmup
        batch = timed("batch", data.batch, count)
        if cfg.compile == "graphs":
            torch.compiler.cudagraph_mark_step_begin()

        def forward(batch=batch):
            with mt.autocast(cfg, device):
                return loss_fn(*batch)

        loss = timed("forward", forward, count)
        optimizer.zero_grad(set_to_none=True)
        timed("backward", loss.backward, count)
        timed("clip", lambda: torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip), count)
        timed("optimizer", optimizer.step, count)
    return {name: 1000 * total / steps for name, total in totals.items()}, model


class HFModel(nn.Module):
    """Linear read-in, transformers.GPT2Model on inputs_embeds, linear read-out (the authors' setup)."""

    def __init__(self, cfg: ModelConfig) -> None:
        from transformers import GPT2Config, GPT2Model

        super().__init__()
        gpt = GPT2Config(
            n_positions=cfg.context,
            n_embd=cfg.width,
            n_layer=cfg.num_layers,
            n_head=cfg.num_heads,
            resid_pdrop=0.0,
            embd_pdrop=0.0,
            attn_pdrop=0.0,
            use_cache=False,
        )
        self.read_in = nn.Linear(cfg.input_dim, cfg.width)
        self.read_out = nn.Linear(cfg.width, cfg.output_dim)
        self.backbone = GPT2Model(gpt)

    def forward(self, inputs: torch.Tensor) -> torch.Tensor:
        hidden = self.backbone(inputs_embeds=self.read_in(inputs)).last_hidden_state  # (B, T, d)
        return self.read_out(hidden)  # (B, T, m)


def hf_step(config: RunConfig, device: torch.device):
    config = mt.resolve_config(config)
    torch.manual_seed(0)
    model = HFModel(config.model).to(device).train()
    optimizer = torch.optim.AdamW(model.parameters(), lr=3e-4, weight_decay=0.01)
    data = mt.TrainingData(config, device)

    def step():
        inputs, targets = data.batch()
        loss = nn.functional.mse_loss(model(inputs), targets)
        optimizer.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        optimizer.step()

    return step


def run(args: argparse.Namespace) -> int:
    if not args.skip_hf:
        require("transformers", "mop bench train (the Hugging Face GPT2Model loop; or pass --skip-hf)")

    device = resolve_device(args.device or "auto")
    steps = args.steps or (5 if device.type == "cpu" else 100)
    warmup = args.warmup if args.warmup is not None else (2 if device.type == "cpu" else 20)
    model = dataclasses.replace(ModelConfig(), num_layers=args.layers, width=args.width, num_heads=args.heads)
    train = TrainConfig(
        batch_size=args.batch_size,
        num_source_systems=1024,
        device=str(device),
        compile=args.compile,
        precision=args.precision,
    )
    config = RunConfig(model=model, train=train)
    result = {
        "device": str(device),
        "threads": torch.get_num_threads(),
        "steps": steps,
        "precision": args.precision,
        "warmup": warmup,
        "ms_per_step": _time(mop_step(config, device), device, warmup, steps),
    }
    if args.phases:
        result["mop_phases_ms"] = mop_phases(config, device, warmup, steps)
    if not args.skip_hf:
        result["hf_gpt2_ms_per_step"] = _time(hf_step(config, device), device, warmup, steps)
        result["speedup"] = result["hf_gpt2_ms_per_step"] / result["ms_per_step"]
    if args.json:
        print(json.dumps(result))
    else:
        print(
            f"device {result['device']} ({result['threads']} threads), "
            f"{steps} timed steps after {warmup} warm-up"
        )
        print(f"mop      {result['ms_per_step']:9.1f} ms/step")
        for name, ms in result.get("mop_phases_ms", {}).items():
            print(f"  {name:<10} {ms:9.2f} ms (synchronised after each phase)")
        if "speedup" in result:
            print(f"hf gpt2  {result['hf_gpt2_ms_per_step']:9.1f} ms/step   speedup {result['speedup']:.2f}x")
    return 0
