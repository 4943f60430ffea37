"""Measure the classical baselines on mop's generators (N test systems, seed 7000001).

Prints the mean over systems of ||yhat_t - y_t||_2 averaged over t in [20, 50) per family and predictor, and
the n4sid-kf / KF mean-squared-error ratios over [10, 20) and [20, 50].

    PYTHONPATH=. python scripts/baselines_check.py [--n 1000] [--predictors kalman,rls,...]
"""

from __future__ import annotations

import argparse
import time

import torch

from mop.config import SystemConfig
from mop.predictors import make_predictor
from mop.systems import generator, make_family

FAMILIES = ("linear", "upper-triangular", "colored-noise")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=1000)
    ap.add_argument("--families", default=",".join(FAMILIES))
    ap.add_argument("--predictors", default="kalman,rls,rls-best,kalman-colored")
    ap.add_argument("--ratio", action="store_true", help="also print n4sid-kf / kalman MSE ratios")
    args = ap.parse_args()
    for fam in args.families.split(","):
        traj = make_family(SystemConfig(family=fam), dtype=torch.float64).generate(
            args.n, 50, generator=generator(7000001)
        )
        y = traj.y[:, :50]
        preds = {}
        for name in args.predictors.split(","):
            if name == "kalman-colored" and fam != "colored-noise":
                continue
            t0 = time.time()
            preds[name] = make_predictor(name).predict(traj)[:, :50]
            err = (preds[name] - y).norm(dim=-1)  # (N, 50)
            print(f"{fam:17s} {name:15s} err[20,50) = {err[:, 20:50].mean():.4f}   ({time.time() - t0:.1f}s)")
        if args.ratio and "kalman" in preds and "n4sid-kf" in preds:
            se = {k: ((v - y) ** 2).sum(-1) for k, v in preds.items()}
            for a, b in ((10, 20), (20, 50)):
                r = se["n4sid-kf"][:, a:b].mean() / se["kalman"][:, a:b].mean()
                print(f"{fam:17s} n4sid-kf / kalman MSE ratio over [{a},{b}) = {r:.3f}")


if __name__ == "__main__":
    main()
