"""`mop bench stream`: online predictions per second, KV-cache streaming vs recomputing the window each step.

An online filter receives one new [y_t, u_t] per system per step and must predict y_{t+1}. For S systems and
N steps:
- stream: `model.step` with the key-value cache, constant cost per step (all N steps timed);
- window: the paper's approach, a full forward over the last `context` inputs at every step. Its cost per
  step is constant once t >= context, so it is timed on `--window-steps` steps past the context and
  reported as a rate.
Weights are random (speed does not depend on them), inputs are N(0, 1). The default model is small
(4 layers, 4 heads, width 64, context 50, learned positions); `--paper` uses the paper's 12/8/256.
max_abs_diff_in_context: largest |stream - full forward| over the first `context` steps.
"""

from __future__ import annotations

import argparse
import json
import time

import torch

from mop.config import ModelConfig
from mop.errors import MopError
from mop.models import build_model

INPUT_DIM = OUTPUT_DIM = 5


def bench_config(paper: bool) -> ModelConfig:
    size = dict(num_layers=12, num_heads=8, width=256) if paper else dict(num_layers=4, num_heads=4, width=64)
    return ModelConfig(**size, context=50, input_dim=INPUT_DIM, output_dim=OUTPUT_DIM)


@torch.no_grad()
def measure(cfg: ModelConfig, num_systems: int, num_steps: int, window_steps: int) -> dict[str, float]:
    C = cfg.context
    if num_steps <= C:
        raise MopError(f"--steps must exceed the context ({C}) to compare streaming with the window")
    model = build_model(cfg).eval()
    z = torch.randn(num_systems, num_steps, cfg.input_dim, generator=torch.Generator().manual_seed(0))

    start = time.perf_counter()
    cache = model.init_cache(num_systems)
    streamed = [model.step(z[:, t], cache) for t in range(num_steps)]  # N x (S, m)
    stream_time = time.perf_counter() - start
    diff = (torch.stack(streamed[:C], 1) - model(z[:, :C])).abs().max().item()

    steps = range(C, min(num_steps, C + window_steps))
    start = time.perf_counter()
    for t in steps:
        model(z[:, t - C + 1 : t + 1])[:, -1]  # (S, m): y_{t+1} from the last C inputs
    window_time = time.perf_counter() - start

    stream_rate = num_systems * num_steps / stream_time
    window_rate = num_systems * len(steps) / window_time
    return {
        "num_systems": num_systems,
        "num_steps": num_steps,
        "window_steps_timed": len(steps),
        "model": f"{cfg.num_layers} layers, {cfg.num_heads} heads, width {cfg.width}, context {C}",
        "torch_threads": torch.get_num_threads(),
        "stream_predictions_per_s": stream_rate,
        "window_predictions_per_s": window_rate,
        "speedup": stream_rate / window_rate,
        "max_abs_diff_in_context": diff,
    }


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--systems", type=int, default=1000, help="systems streamed in parallel (1000)")
    parser.add_argument("--steps", type=int, default=1000, help="time steps per system (1000)")
    parser.add_argument(
        "--window-steps",
        type=int,
        default=100,
        help="steps past the context on which the window baseline is timed (100)",
    )
    parser.add_argument("--paper", action="store_true", help="the paper's 12-layer, 8-head, width-256 model")


def run(args: argparse.Namespace) -> int:
    if args.systems <= 0 or args.window_steps <= 0:
        raise MopError("--systems and --window-steps must be positive")
    r = measure(bench_config(args.paper), args.systems, args.steps, args.window_steps)
    if args.json:
        print(json.dumps(r, indent=2))
        return 0
    print(
        f"online prediction, {r['num_systems']} systems x {r['num_steps']} steps, model: {r['model']}, "
        f"float32, {r['torch_threads']} torch threads"
    )
    print(f"stream (KV cache):  {r['stream_predictions_per_s']:>12,.0f} predictions/s")
    print(
        f"window (recompute): {r['window_predictions_per_s']:>12,.0f} predictions/s "
        f"(timed on {r['window_steps_timed']} steps)"
    )
    print(
        f"speedup {r['speedup']:.1f}x, "
        f"max |stream - forward| inside the context {r['max_abs_diff_in_context']:.1e}"
    )
    return 0
