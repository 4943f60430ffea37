"""k-step forecast errors against k for MOP and baselines on fresh test systems of a run's family.

    python scripts/forecast_errors.py RUN_DIR --predictors kalman rls --steps 10 --num-systems 500

Error at horizon k (k = 1 is the one-step prediction): mean over test systems and forecast origins t >= 20
(with t + k - 1 <= T) of ||y_{t+k-1} - forecast[:, t, k-1]||_2 (mop.experiments.analyses.horizon_errors).
Test systems: the run's system config, horizon T = the run's train.horizon, seed --seed (not the train seed).
"""

from __future__ import annotations

import argparse
import time

import torch

from mop.experiments.analyses import horizon_errors
from mop.predictors import forecast, make_predictor
from mop.runs import load_config
from mop.systems import FAMILIES


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("run_dir")
    ap.add_argument("--predictors", nargs="+", default=["kalman", "rls"])
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--num-systems", type=int, default=500)
    ap.add_argument("--seed", type=int, default=12345)
    ap.add_argument("--start", type=int, default=20)
    args = ap.parse_args()
    cfg = load_config(args.run_dir)
    family = FAMILIES.get(cfg.system.family)(cfg.system)
    gen = torch.Generator().manual_seed(args.seed)
    traj = family.generate(args.num_systems, cfg.train.horizon, generator=gen)
    print(f"{cfg.system.family}: N = {args.num_systems}, T = {traj.horizon}, origins t >= {args.start}")
    rows = {}
    for name in ["mop", *args.predictors]:
        t0 = time.time()
        p = make_predictor(name, shared={"run_dir": args.run_dir})
        rows[name] = horizon_errors(traj.y, forecast(p, traj, args.steps), args.start)
        print(f"  {name}: {time.time() - t0:.1f} s", flush=True)
    print("| k | " + " | ".join(rows) + " |")
    print("|---" * (len(rows) + 1) + "|")
    for k in range(args.steps):
        print(f"| {k + 1} | " + " | ".join(f"{rows[n][k]:.3f}" for n in rows) + " |")


if __name__ == "__main__":
    main()
