"""`mop fit arx|n4sid EST --out MODEL`: fit the system-identification field's baselines once on an estimation
record (.csv `trajectory,t,y0..,u0..` or .npz), their orders chosen on the last 20% of each trajectory
(mop.identify.select), and save them as MODEL/fitted.json; `mop predict MODEL VAL.csv [--simulate C]` then
predicts or simulates with the fitted model, fixed. The fit is mop.estimators' ARX / N4SID."""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

from mop.errors import MopWarning
from mop.estimators import IDENTIFIED
from mop.identify import IDENTIFIERS, save
from mop.identify.select import CRITERIA, HOLDOUT, POLE_RADIUS, SCORE, SIMULATION, TOLERANCE
from mop.io import reading_once
from mop.record import read_records

EXAMPLES = """
grids: arx p = 1..P, q = 1..P (q = 0 without inputs); n4sid n = 1..P; P = --max-order.
examples:
  mop fit arx est.csv --out arx_model
  mop fit n4sid est.csv --out n4sid_model --select one-step --max-order 6
  mop predict arx_model val.csv --simulate 50
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.epilog = EXAMPLES
    parser.add_argument("kind", choices=IDENTIFIERS.names(), help="the identifier")
    parser.add_argument("data", help="estimation record: .csv (trajectory,t,y0..,u0..) or .npz (y, u)")
    parser.add_argument("--out", required=True, help="directory to write fitted.json into")
    parser.add_argument(
        "--select",
        choices=CRITERIA,
        default=SIMULATION,
        help="score the orders on the held-out steps in free-run simulation (default) or one step ahead",
    )
    parser.add_argument("--max-order", type=int, default=10, help="largest order of the grid (10)")


def run(args: argparse.Namespace) -> int:
    estimator = IDENTIFIED[args.kind](select=args.select, max_order=args.max_order)
    with reading_once():  # the estimator and the summary read the record once
        fitted = estimator.fit(args.data).predictor_
        records = read_records(args.data)
    steps = sum(len(r) for r in records)
    print(
        f"{args.kind}: {len(records)} trajectory(ies), {steps} steps; orders scored by {args.select} RMSE "
        f"on the last {HOLDOUT:.0%} of each trajectory (the smallest within {TOLERANCE:.0%} of the best wins)"
    )
    for row in fitted.info["grid"]:
        orders = ", ".join(f"{k}={v}" for k, v in row.items() if k != SCORE)
        rmse = "diverged" if row[SCORE] is None else f"{row[SCORE]:.4g}"
        print(f"  {orders:>12}  held-out rmse {rmse}")
    chosen = ", ".join(f"{k}={v}" for k, v in fitted.orders.items())
    path = save(fitted, args.out)
    print(f"chosen {chosen}, refitted on the whole record; wrote {path}")
    radius = fitted.info[POLE_RADIUS]
    if radius >= 1:
        warnings.warn(
            MopWarning(
                f"the chosen model is unstable (largest pole modulus {radius:.4g} >= 1): its free run does "
                "not decay and simulations of long records can grow without bound; unless the plant is "
                "unstable, compare --select one-step, a lower --max-order or the other identifier"
            ),
            stacklevel=2,
        )
    print(f"next: mop predict {Path(args.out)} VAL.csv [--simulate C | --steps K]")
    return 0
