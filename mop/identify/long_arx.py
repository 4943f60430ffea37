"""Longer ARX orders for the records recipe's feature, chosen by free-run simulation of held-out data.

`mop fit arx` searches ARX orders up to 10, the orders of the field's small benchmarks. A long record of a
lightly damped structure supports far longer ones: on the F-16 ground vibration test (Acceleration1, four
estimation records, 294,912 samples) the least-squares ARX(p, p) with an intercept simulates Levels 2 / 4 / 6
at 0.284 / 0.487 / 0.629 m/s^2 for p = 10, 0.263 / 0.429 / 0.551 for p = 20 and 0.246 / 0.381 / 0.494 for
p = 40 (the held-out end of the estimation records falls alike: 0.473, 0.424, 0.377), where `mop fit arx`'s
ARX(10, 10) scores 0.284 / 0.486 / 0.636.

choose_long_orders fits ARX(p, p) for each p of LONG_ORDERS, and the ARX(p0, q0) `mop fit arx` chose, by
the least squares the feature starts from (mop.filters.arx.least_squares_coefficients, ridge RIDGE) on
the first 80% of each record, simulates the last SELECTION_SHARE from the inputs after the measured outputs
before it (mop.identify.cubic.simulate_narx), and keeps the fewest coefficients within TOLERANCE of the
lowest RMSE. A long candidate is only tried where the fitting part holds PAIRS_PER_COEFFICIENT pairs per
coefficient, so records of a few thousand samples keep the orders `mop fit arx` chose. LONG_ORDERS stop
at 40: the feature predicts the last value for its first max(p, q) steps, which must end inside the 50
measured outputs a benchmark's simulation starts from (mop.recipe.selection.INIT_WINDOW).
"""

from __future__ import annotations

import math

import numpy as np

from mop.filters.arx import least_squares_coefficients
from mop.identify.cubic import SELECTION_SHARE, simulate_narx
from mop.identify.linear import Arrays
from mop.identify.select import TOLERANCE

LONG_ORDERS = (15, 20, 30, 40)
PAIRS_PER_COEFFICIENT = 50
RIDGE = 1e-6  # relative, as the records recipe's fit_prior (mop.train.records.RIDGE)


def coefficient_count(p: int, q: int, m: int, k: int) -> int:
    """Coefficients per output of the ARX(p, q) with an intercept on m outputs and k inputs."""
    return p * m + q * k + 1


def choose_long_orders(
    parts: Arrays, p: int, q: int, max_order: int = max(LONG_ORDERS)
) -> tuple[int, int, dict[str, float]]:
    """(p, q) of the lowest held-out simulation RMSE among ARX(p, q) and ARX(P, P), P in LONG_ORDERS up to
    max_order with enough pairs (module docstring), for `parts` [(y (L, m), u (L, k))] normalised as the
    network reads them; the fewest coefficients within TOLERANCE of the lowest win. Returns the scores by
    "p,q" too (inf: the simulation left BLOW_UP times the scored outputs' range). Without inputs, or where
    no long order has enough pairs, (p, q) unchanged and no scores."""
    m, k = parts[0][0].shape[1], parts[0][1].shape[1]
    fits, tails = [], []
    for y, u in parts:
        cut = len(y) - math.ceil(SELECTION_SHARE * len(y))
        if cut > 2 * max(LONG_ORDERS) and len(y) - cut >= 2:
            fits.append(np.concatenate([y[:cut], u[:cut]], axis=1))
            tails.append((y, u, cut))
    pairs = sum(len(a) for a in fits)
    enough = lambda P: pairs >= PAIRS_PER_COEFFICIENT * coefficient_count(P, P, m, k)  # noqa: E731
    long = [P for P in LONG_ORDERS if max(p, q) < P <= max_order and enough(P)]
    if k == 0 or not long:
        return p, q, {}
    candidates = [(p, q), *((P, P) for P in long)]
    scores = {f"{a},{b}": _score(fits, tails, m, a, b) for a, b in candidates}
    best = min(scores.values())
    good = [c for c in candidates if scores[f"{c[0]},{c[1]}"] <= (1 + TOLERANCE) * best]
    chosen = min(good, key=lambda c: coefficient_count(*c, m, k))
    return chosen[0], chosen[1], scores


def _score(fits: list[np.ndarray], tails: list, m: int, p: int, q: int) -> float:
    """Held-out simulation RMSE of the least-squares ARX(p, q) with an intercept (inf where it blew up)."""
    theta = least_squares_coefficients(fits, m, p, q, True, ridge=RIDGE)
    r = max(p, q)
    errors = []
    for y, u, cut in tails:
        start = cut - r
        sim = simulate_narx(theta, y[start:], u[start:], p, q, 0, r)
        if not np.isfinite(sim).all():
            return math.inf
        errors.append(sim - y[cut:])
    return float(np.sqrt(np.mean(np.concatenate(errors) ** 2)))
