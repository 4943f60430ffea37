"""ARX, N4SID and the learned model on one record, from Python: fit each on the first 70%, simulate the last
30% from its inputs alone after 50 outputs, print the simulation RMSE.

    python examples/compare_estimators.py [RECORD.csv] [--minutes M] [--tiny]

RECORD.csv: mop.io's CSV (trajectory,t,y0..,u0..; its first record is used); without it, a seeded Wiener
system stands in (a damped second-order plant driven by a random input, its output through tanh, measured
with noise; 1000 steps). --minutes: the learned model's training budget (2); --tiny: a tiny model trained a
few steps (seconds, for the test suite; its numbers mean little). The ten lines that matter are in compare().

Measured on the Wiener system (2-core CPU, one thread; the output's std 0.78; 23 s in all, the learned model's
records recipe of 1000 steps well inside its 2 minutes): simulation RMSE over the last 250 steps ARX 0.396,
N4SID 0.364, Learned 0.293.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

import mop
from mop.estimators import ARX, N4SID, Learned
from mop.records import scores

TINY = dict(model__num_layers=1, model__width=16, model__num_heads=2, model__context=16,
            train__horizon=16, train__batch_size=8, train__steps=4, train__log_every=2)  # fmt: skip


def compare(record: mop.Record, minutes: float, **options: object) -> dict[str, float]:
    est, val = record.split(0.3)  # the last 30% validates
    rmse = {}
    for model in (ARX(), N4SID(), Learned(budget_minutes=minutes, **options)):
        ysim = model.fit(est).simulate(val, init=50)  # (T, m): NaN before t = 50
        rmse[model.name] = scores(val.y[50:], ysim[50:]).rmse
        print(f"{model.name:>8}: simulation RMSE {rmse[model.name]:.4g}")
    return rmse


def wiener_record(steps: int = 1000, seed: int = 0) -> mop.Record:
    """y_t = tanh(x1_t) + noise, x_{t+1} = A x_t + b u_t (poles 0.9 +- 0.3 i), u ~ N(0, 1) held 3 steps."""
    rng = np.random.default_rng(seed)
    A, b = np.array([[1.8, -0.9], [1.0, 0.0]]), np.array([0.15, 0.0])
    u, x, y = np.repeat(rng.normal(size=steps // 3 + 1), 3)[:steps], np.zeros(2), np.zeros(steps)
    for t in range(steps):
        y[t] = np.tanh(x[0]) + 0.02 * rng.normal()
        x = A @ x + b * u[t]
    return mop.Record(y=y, u=u, sampling_time=1.0, name="wiener")


def main(argv: list[str] | None = None) -> dict[str, float]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("record", nargs="?", help="a CSV record (default: a simulated Wiener system)")
    parser.add_argument("--minutes", type=float, default=2.0, help="the learned model's budget (2)")
    parser.add_argument("--tiny", action="store_true", help="a tiny learned model, a few steps (tests)")
    args = parser.parse_args(argv)
    record = mop.read_records(args.record)[0] if args.record else wiener_record()
    return compare(record, args.minutes, **(TINY if args.tiny else {}))


if __name__ == "__main__":
    main(sys.argv[1:])
