"""`mop bench forecast`: k-step forecast time against T and K, beside the one-step predict, per predictor.

For each horizon T in --horizons and each K in --steps, every predictor runs predict (one-step) and
forecast(K) on the same seeded linear systems (output_dim 5) in one process, so the columns are ratios
measured side by side. Predictors: the learned model (random weights, 2 layers, 4 heads, width 64,
context 50, the small preset's size; `--paper` uses 12/8/256) in the paper's window mode, the same model with
direct k-step heads (`mop-direct`: model.horizons = the largest K, model.forecast_mode = "direct"; one
forward gives every step, so its forecast costs about its one-step predict), and the filters kalman,
kalman-colored (on colored-noise systems), rls. What it shows: forecast / predict stays near
constant as T grows (cost linear in T) and grows with K by the work of the new inputs only.
Writes a table (stdout, or --json) and, with --plot FILE, forecast seconds against T (one line per
predictor and K, predict dashed).
"""

from __future__ import annotations

import argparse
import json
import time

import torch

from mop.config import ModelConfig, SystemConfig
from mop.errors import MopError
from mop.models import build_model
from mop.models.predictor import LearnedPredictor
from mop.predictors import forecast, make_predictor
from mop.systems import generator, make_family


def _timed(fn) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


NAMES = ("mop", "mop-direct", "kalman", "kalman-colored", "rls")


def predictors(paper: bool, heads: int = 10) -> dict[str, tuple[object, str]]:
    """name -> (predictor, family it runs on); mop-direct has `heads` k-step heads."""
    size = dict(num_layers=12, num_heads=8, width=256) if paper else dict(num_layers=2, num_heads=4, width=64)
    torch.manual_seed(0)
    cfg = ModelConfig(**size, context=50, input_dim=5, output_dim=5)
    model = build_model(cfg).eval()
    direct = ModelConfig(**{**cfg.__dict__, "horizons": max(heads, 2), "forecast_mode": "direct"})
    return {
        "mop": (LearnedPredictor(model), "linear"),
        "mop-direct": (LearnedPredictor(build_model(direct).eval()), "linear"),
        "kalman": (make_predictor("kalman"), "linear"),
        "kalman-colored": (make_predictor("kalman-colored"), "colored-noise"),
        "rls": (make_predictor("rls"), "linear"),
    }


def measure(num_systems: int, horizons: list[int], steps: list[int], paper: bool, names: list[str]) -> list:
    """Rows {predictor, T, K, predict_s, forecast_s, ratio}; K = 1 rows are predict alone."""
    rows, table = [], predictors(paper, max(steps))
    for name in names:
        predictor, family = table[name]
        for T in horizons:
            traj = make_family(SystemConfig(family=family), dtype=torch.float64).generate(
                num_systems, T, generator=generator(0)
            )
            if name.startswith("mop"):
                traj.y = traj.y.float()
            one = _timed(lambda p=predictor, tr=traj: p.predict(tr))
            for K in steps:
                f = _timed(lambda p=predictor, tr=traj, k=K: forecast(p, tr, k))
                rows.append(dict(predictor=name, T=T, K=K, predict_s=one, forecast_s=f, ratio=f / one))
    return rows


def plot(rows: list, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for name in dict.fromkeys(r["predictor"] for r in rows):
        mine = [r for r in rows if r["predictor"] == name]
        first = [r for r in mine if r["K"] == mine[0]["K"]]
        (line,) = ax.plot(
            [r["T"] for r in first], [r["predict_s"] for r in first], "--", label=f"{name} predict"
        )
        for K in dict.fromkeys(r["K"] for r in mine):
            pts = [r for r in mine if r["K"] == K]
            ax.plot([r["T"] for r in pts], [r["forecast_s"] for r in pts], "-o", color=line.get_color(), ms=3)
            ax.annotate(f"K={K}", (pts[-1]["T"], pts[-1]["forecast_s"]), fontsize=7)
    ax.set(xlabel="T (steps per trajectory)", ylabel="seconds", xscale="log", yscale="log")
    ax.set_title(f"forecast (solid) vs one-step predict (dashed), {torch.get_num_threads()} torch threads")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--systems", type=int, default=200, help="systems per batch (200)")
    parser.add_argument("--horizons", default="50,100,200", help="comma-separated T values (50,100,200)")
    parser.add_argument("--steps", default="1,10", help="comma-separated K values (1,10)")
    parser.add_argument("--predictors", default=",".join(NAMES), help="which to time")
    parser.add_argument("--paper", action="store_true", help="the paper's 12-layer, 8-head, width-256 model")
    parser.add_argument("--plot", help="write the figure to this file (.png or .pdf)")


def _ints(text: str, flag: str) -> list[int]:
    try:
        values = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise MopError(f"{flag} must be comma-separated integers, got {text!r}") from None
    if not values or min(values) < 1:
        raise MopError(f"{flag} must be positive integers, got {text!r}")
    return values


def run(args: argparse.Namespace) -> int:
    horizons, steps = _ints(args.horizons, "--horizons"), _ints(args.steps, "--steps")
    names = [n.strip() for n in args.predictors.split(",") if n.strip()]
    unknown = [n for n in names if n not in NAMES]
    if unknown or args.systems < 1:
        raise MopError(f"--predictors takes {', '.join(NAMES)} (got {unknown}); --systems must be >= 1")
    rows = measure(args.systems, horizons, steps, args.paper, names)
    if args.plot:
        plot(rows, args.plot)
    if args.json:
        print(json.dumps({"torch_threads": torch.get_num_threads(), "rows": rows}, indent=2))
        return 0
    print(f"forecast vs predict, {args.systems} systems, {torch.get_num_threads()} torch threads")
    print(f"{'predictor':>15} {'T':>5} {'K':>4} {'predict s':>10} {'forecast s':>11} {'ratio':>6}")
    for r in rows:
        print(
            f"{r['predictor']:>15} {r['T']:>5} {r['K']:>4} {r['predict_s']:>10.3f} "
            f"{r['forecast_s']:>11.3f} {r['ratio']:>6.2f}"
        )
    return 0
