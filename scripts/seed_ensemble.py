"""The mean of several `mop benchmark` runs' free-run simulations (one run per training seed), scored as one
predictor by the official protocol's RMSE.

    python scripts/seed_ensemble.py OUT OUT [OUT ...] [--predictor mop]

Each OUT is a `mop benchmark --out OUT` folder; for every benchmark test that all of them hold
(OUT/BENCHMARK/TEST_PREDICTOR.csv: trajectory, t, y0.., ysim0.. over the scored steps t >= n), the
simulations are averaged step by step and the line gives each run's RMSE and the ensemble's, in the
output's units (pooled over the output channels, as `mop benchmark` scores them). The ensemble costs the
runs' training time together: three seeds of `--budget 30` are 90 minutes of training.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def read_simulation(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(y (T, m), ysim (T, m)) of a simulation CSV, its rows in the file's order."""
    header = path.read_text().splitlines()[0].split(",")
    rows = np.loadtxt(path, delimiter=",", skiprows=1, usecols=range(2, len(header)), ndmin=2)
    m = sum(name.startswith("ysim") for name in header)
    return rows[:, :m], rows[:, m:]


def rmse(y: np.ndarray, sim: np.ndarray) -> float:
    return float(np.sqrt(np.mean((y - sim) ** 2)))


def ensemble(paths: list[Path]) -> tuple[list[float], float]:
    """(each simulation's RMSE, the RMSE of their mean) for simulations of the same test."""
    read = [read_simulation(p) for p in paths]
    y = read[0][0]
    for p, (other, _) in zip(paths[1:], read[1:], strict=True):
        if other.shape != y.shape or not np.allclose(other, y):
            sys.exit(f"{p} scores other measured outputs than {paths[0]}: give runs of the same test")
    mean = np.mean([sim for _, sim in read], axis=0)
    return [rmse(y, sim) for _, sim in read], rmse(y, mean)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("outs", nargs="+", type=Path, help="`mop benchmark --out` folders, one per seed")
    parser.add_argument("--predictor", default="mop", help="the predictor's simulations to average (mop)")
    args = parser.parse_args()
    if len(args.outs) < 2:
        sys.exit("give two or more `mop benchmark --out` folders")
    suffix = f"_{args.predictor.replace(':', '-')}.csv"
    first = sorted(args.outs[0].glob(f"*/*{suffix}"))
    shared = [
        p.relative_to(args.outs[0])
        for p in first
        if all((o / p.relative_to(args.outs[0])).is_file() for o in args.outs)
    ]
    if not shared:
        sys.exit(f"no test simulation *{suffix} is in every folder given")
    for rel in shared:
        each, mean = ensemble([o / rel for o in args.outs])
        test = rel.name.removesuffix(suffix)
        runs = " / ".join(f"{v:.4g}" for v in each)
        print(f"{rel.parent.name} {test}: runs {runs}; their mean simulation {mean:.4g}")


if __name__ == "__main__":
    main()
