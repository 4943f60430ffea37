"""`mop bench predict`: one-step prediction of long records with a context-limited model, per mode.

A trained model (default pretrained:lti-siso, context C = 500) predicts --records records of --steps steps
simulated from the family it was trained on (--seed), as `mop predict` does, in each mode of
mop.models.predict:
- window (the default): half-overlapping windows of C inputs every C/2 steps, about 2 T / C forwards;
- stream: the KV cache, one step per sample (an approximation beyond C);
- sliding: the paper's exact window, one forward per step beyond C; timed on the first --sliding-records
  records only, and compared with window on those (seconds per record, RMSE ratio).
Reported per mode: wall seconds, the RMSE over every step (t >= 1) and over the steps beyond the context
(t > C, where the modes differ). A model without a context limit gives one path for every mode.
"""

from __future__ import annotations

import argparse
import json
import time

import torch
from torch import Tensor

from mop.errors import MopError
from mop.runs import load_config, load_predictor
from mop.systems import Trajectories, generator, make_family


def _rmse(yhat: Tensor, y: Tensor, start: int) -> float:
    """RMSE of yhat (B, T+1, m) against y over steps t >= start."""
    return float((yhat[:, start:] - y[:, start:]).double().pow(2).mean().sqrt())


def _run(model: str, mode: str, traj: Trajectories) -> dict[str, float]:
    """Records, wall seconds of predict in `mode` on traj and its RMSE over t >= 1 and t > C."""
    p = load_predictor(model, mode=mode)
    start = time.perf_counter()
    yhat = p.predict(traj)  # (B, T+1, m)
    seconds = time.perf_counter() - start
    context = p.cfg.context
    return {
        "records": traj.num_systems,
        "seconds": seconds,
        "rmse_all": _rmse(yhat, traj.y, 1),
        "rmse_beyond": _rmse(yhat, traj.y, context + 1),
    }


def measure(model: str, records: int, steps: int, seed: int, sliding_records: int) -> dict:
    """{the setting, window, stream, sliding (on its records), window_on_sliding_records, the two ratios}."""
    config = load_config(model)
    traj = make_family(config.system).generate(records, steps, generator=generator(seed))
    out = {
        "model": model,
        "context": config.model.context,
        "records": records,
        "steps": steps,
        "seed": seed,
        "torch_threads": torch.get_num_threads(),
        "window": _run(model, "window", traj),
        "stream": _run(model, "stream", traj),
    }
    subset = traj.select(slice(0, sliding_records))
    out["sliding"] = _run(model, "sliding", subset)
    out["window_on_sliding_records"] = _run(model, "window", subset)
    sliding, window = out["sliding"], out["window_on_sliding_records"]
    out["sliding_over_window_seconds"] = sliding["seconds"] / window["seconds"]
    out["window_over_sliding_rmse_beyond"] = window["rmse_beyond"] / sliding["rmse_beyond"]
    return out


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--model", default="pretrained:lti-siso", help="run directory or pretrained:NAME")
    parser.add_argument("--records", type=int, default=100, help="records predicted (100)")
    parser.add_argument("--steps", type=int, default=1000, help="steps T per record (1000)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the simulated records (0)")
    parser.add_argument(
        "--sliding-records", type=int, default=8, help="records the slow exact sliding window runs on (8)"
    )


def run(args: argparse.Namespace) -> int:
    if args.records <= 0 or args.steps <= 0 or not 0 < args.sliding_records <= args.records:
        raise MopError("--records and --steps must be positive, --sliding-records in [1, --records]")
    r = measure(args.model, args.records, args.steps, args.seed, args.sliding_records)
    if args.json:
        print(json.dumps(r, indent=2))
        return 0
    print(
        f"one-step predict, {r['model']} (context {r['context']}), {r['records']} records x {r['steps']} "
        f"steps (seed {r['seed']}), {r['torch_threads']} torch threads"
    )
    print(f"{'mode':>28} {'records':>8} {'seconds':>9} {'rmse t>=1':>10} {'rmse t>C':>10}")
    rows = [("window (default)", "window"), ("stream", "stream"), ("sliding (exact)", "sliding")]
    rows.append(("window on the sliding records", "window_on_sliding_records"))
    for label, key in rows:
        m = r[key]
        rmse = f"{m['rmse_all']:>10.4g} {m['rmse_beyond']:>10.4g}"
        print(f"{label:>28} {m['records']:>8} {m['seconds']:>9.2f} {rmse}")
    print(
        f"sliding / window seconds {r['sliding_over_window_seconds']:.1f}x, window / sliding RMSE beyond "
        f"the context {r['window_over_sliding_rmse_beyond']:.3f}"
    )
    return 0
