"""How far the Bayes predictor over a family is from the Kalman filter that knows the system, with a bank
grown until the estimate settles: the `bayes` predictor (mop.filters.bayes) over SHARDS x SIZE systems drawn
from the experiment's test family, its shards run in separate processes (one torch thread each) and combined
(mop.filters.bayes.BankSums), on the test systems `mop reproduce EXPERIMENT --preset PRESET --seed SEED`
evaluates (its first condition). Prints, as the shards add up, the bank's MSE ratio to the KF over
t in [START, T] (paired bootstrap 95% CI over test systems) and the median effective sample size at t = START
and t = T, and writes the rows to OUT (JSON) if given.

    python scripts/bayes_bank.py examples/dead_time.toml --shards 10 [--size 20000] [--jobs 2]
        [--preset small] [--seed 0] [--start 20] [--out bank.json]

Shard i draws its systems with seed SEED + i (draw_bank), so the first shard's row is the `bayes` row of
the experiment's report at the default bank_size of 20000. Each row's bank is an achievable predictor that
reads only the past and the family: its ratio is an upper bound of the Bayes predictor's, and where the rows
stop moving as the bank doubles, the estimate of it. Cost: about 2 min of one core per shard of 20000
systems (N = 500, T = 50, n = 5).
"""

from __future__ import annotations

import argparse
import functools
import json
import multiprocessing
import sys
from pathlib import Path

import numpy as np
import torch

from mop.errors import MopError
from mop.experiments import run_config
from mop.experiments.evaluating import test_system, test_trajectories
from mop.experiments.files import load_experiment
from mop.experiments.presets import get_preset
from mop.filters.bayes import BankSums, bank_sums, draw_bank
from mop.metrics import mse_ratio_ci
from mop.predictors import make_predictor
from mop.systems.base import Trajectories


@functools.lru_cache(maxsize=1)
def test_set(path: str, preset: str, seed: int) -> tuple[object, Trajectories]:
    """(the test family's SystemConfig, its test trajectories) of the experiment's first condition (once per
    process: a worker runs several shards)."""
    exp = load_experiment(path)
    trained = run_config(exp, preset, seed)
    system = test_system(trained, exp.conditions[0])
    return system, test_trajectories(system, get_preset(preset).num_test_systems, trained.train.horizon, seed)


def shard(args: tuple[str, str, int, int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(lse, lse2, mean) of shard i: SIZE systems drawn with seed SEED + i, over the test set."""
    path, preset, seed, size, i = args
    torch.set_num_threads(1)
    system, traj = test_set(path, preset, seed)
    sums = bank_sums(draw_bank(system, size, seed + i, traj.horizon), traj.y, traj.u)
    return sums.lse.numpy(), sums.lse2.numpy(), sums.mean.numpy()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("experiment", help="an experiment file (.toml) of a linear-Gaussian family")
    parser.add_argument("--shards", type=int, default=10)
    parser.add_argument("--size", type=int, default=20_000, help="systems per shard")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--preset", default="small")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--start", type=int, default=20, help="the error window's first step")
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    torch.set_num_threads(1)
    try:  # a missing file or a family without a linear-Gaussian model: one line, before any shard runs
        system, traj = test_set(args.experiment, args.preset, args.seed)
        draw_bank(system, 1, args.seed, traj.horizon)
    except MopError as err:
        sys.exit(f"bayes_bank: {err}")
    y = traj.y.double()
    e_kf = (make_predictor("kalman").predict(traj).double() - y).norm(dim=-1).numpy()
    tasks = [(args.experiment, args.preset, args.seed, args.size, i) for i in range(args.shards)]
    rows, sums = [], None
    with multiprocessing.get_context("spawn").Pool(args.jobs) as pool:
        for i, (lse, lse2, mean) in enumerate(pool.imap(shard, tasks)):
            part = BankSums(*(torch.from_numpy(a) for a in (lse, lse2, mean)))
            sums = part if sums is None else sums + part
            e = (sums.mean[:, :, 0] - y).norm(dim=-1).numpy()
            ratio, low, high = mse_ratio_ci(e, e_kf, args.start, e.shape[1])
            ess = sums.ess.numpy()
            row = {
                "systems": (i + 1) * args.size,
                "ratio": ratio,
                "ci": [low, high],
                "ess_start": float(np.median(ess[:, args.start])),
                "ess_end": float(np.median(ess[:, -1])),
            }
            rows.append(row)
            T, ess_start, ess_end = e.shape[1] - 1, row["ess_start"], row["ess_end"]
            print(
                f"{row['systems']:>8} systems: bayes / KF over t in [{args.start}, {T}] {ratio:.3f} "
                f"[{low:.3f}, {high:.3f}], median ESS {ess_start:.1f} at t = {args.start}, "
                f"{ess_end:.1f} at t = {T}",
                flush=True,
            )
    if args.out:
        args.out.write_text(json.dumps({"experiment": args.experiment, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
