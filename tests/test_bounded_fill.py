"""The learned models' ARX feature across missing outputs holds its free run within the measured outputs'
range widened by twice its span (mop.filters.rls.fill_bounds): the clipped recursion against numpy, the
baselines' plain recursion unchanged, and a shipped class model that used to simulate to NaN."""

import numpy as np
import torch

import mop
from mop.config import SystemConfig
from mop.filters.arx import arx_predict
from mop.filters.rls import FILL_MARGIN, fill_bounds
from mop.systems import make_family
from mop.systems.base import Trajectories

UNSTABLE = 1.5  # y_{t+1} = 1.5 y_t: an AR(1) fit that diverges in a free run


def measured_then_missing(measured: int = 10, total: int = 40) -> torch.Tensor:
    y = torch.full((1, total, 1), float("nan"), dtype=torch.float64)
    y[0, :measured, 0] = torch.sin(torch.arange(measured, dtype=torch.float64))
    return y


def free_run(y: np.ndarray, theta: float, low: float, high: float) -> np.ndarray:
    """numpy: yhat_t = clip(theta y~_{t-1}, low, high) wherever y_{t-1} was missing or filled."""
    filled, preds = y.copy(), np.zeros_like(y)
    for t in range(2, len(y)):
        preds[t] = theta * filled[t - 1]
        if np.isnan(y[t - 1]):
            preds[t] = min(max(preds[t], low), high)
        filled[t] = y[t] if not np.isnan(y[t]) else preds[t]
    return preds


def test_the_bounded_fill_is_the_clipped_free_run():
    y = measured_then_missing()
    prior = (torch.tensor([[UNSTABLE]], dtype=torch.float64), 1e-12)  # held: the pairs barely move it
    got = arx_predict(y, None, 1, 1, prior=prior, bounded=0)[0, :, 0].numpy()
    seen = y[0, :10, 0].numpy()
    span = seen.max() - seen.min()
    low, high = seen.min() - 2 * span, seen.max() + 2 * span
    expect = free_run(y[0, :, 0].numpy(), UNSTABLE, low, high)
    np.testing.assert_allclose(got[11:], expect[11:], rtol=1e-9, atol=1e-9)
    assert np.isclose(got[11:].max(), high) or np.isclose(got[11:].min(), low)  # the bound binds
    plain = arx_predict(y, None, 1, 1, prior=prior)[0, :, 0].numpy()  # the baselines' recursion
    np.testing.assert_allclose(plain[11:], free_run(y[0, :, 0].numpy(), UNSTABLE, -np.inf, np.inf)[11:])
    assert np.abs(plain[-1]) > 1e3 * span


def test_a_complete_record_is_not_bounded():
    y = measured_then_missing(measured=40)
    y[0, :, 0] *= torch.linspace(1, 5, 40, dtype=torch.float64)  # beyond any earlier range: read, not filled
    u = torch.randn(1, 40, 1, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    bounded = arx_predict(y, u, 2, 2, offset=True, bounded=0)
    torch.testing.assert_close(bounded, arx_predict(y, u, 2, 2, offset=True), rtol=0, atol=0)


def test_the_wiener_hammerstein_model_simulates_a_short_context_finitely():
    """pretrained:wiener-hammerstein on a held-out system of its class, simulated after 50 steps: its
    in-context ARX(10, 10) fitted on 50 steps is unstable, and the simulation reached 1e13 and then NaN
    (scripts/carry_over.py plant 2); bounded, it stays finite, near its feature's bounds (the context's range
    widened by twice its span; a margin of one more span for the network's correction)."""
    family = make_family(SystemConfig(family="wiener-hammerstein"))
    params = family.sample(1, generator=torch.Generator().manual_seed(1002))
    traj = family.simulate(params, 2047, generator=torch.Generator().manual_seed(21))
    y, u = traj.y[:, 1024:], traj.u[:, 1024:]
    sim = mop.load("pretrained:wiener-hammerstein").simulate(Trajectories(y, u), 50)
    assert torch.isfinite(sim).all()
    lo, hi = y[0, :50].min(), y[0, :50].max()
    assert (sim > lo - 3 * (hi - lo)).all() and (sim < hi + 3 * (hi - lo)).all()


def test_rows_before_the_first_and_a_record_at_rest_set_no_bounds():
    """fill_bounds counts measured outputs from row `first` on (a fitted start's assumed values before it),
    and a channel whose measured outputs are all equal (span 0) stays unbounded."""
    y = measured_then_missing(measured=15)
    low, high = fill_bounds(y, first=6)  # 9 rows from row 6 on: fewer than FILL_MIN_SEEN
    assert torch.isinf(low).all() and torch.isinf(high).all()
    low, high = fill_bounds(y, first=5)  # 10 rows: bounded from row 14 on, by rows 5..14 alone
    seen = y[0, 5:15, 0]
    assert torch.isinf(low[0, :14]).all()
    assert low[0, 14, 0] == seen.min() - FILL_MARGIN * (seen.max() - seen.min())
    y[0, :15, 0] = 1.5
    low, high = fill_bounds(y)
    assert torch.isinf(low).all() and torch.isinf(high).all()


def test_a_known_range_widens_the_bounds_from_step_zero():
    """known_range: the outputs measured before the record count as seen from step 0 (closed form)."""
    y = measured_then_missing(measured=3)  # 3 measured: alone, fewer than FILL_MIN_SEEN
    known = torch.tensor([[-4.0], [6.0]], dtype=torch.float64)
    low, high = fill_bounds(y, known_range=known)
    seen = y[0, :3, 0]
    lo, hi = min(float(seen.min()), -4.0), max(float(seen.max()), 6.0)
    span = FILL_MARGIN * (hi - lo)
    np.testing.assert_allclose(low[0, :, 0].numpy(), lo - span)
    np.testing.assert_allclose(high[0, :, 0].numpy(), hi + span)
    inside = torch.tensor([[0.0], [0.5]], dtype=torch.float64)  # within the record's own range: no change
    y = measured_then_missing(measured=15)
    torch.testing.assert_close(fill_bounds(y, known_range=inside)[0][:, 14:], fill_bounds(y)[0][:, 14:])


def test_the_free_run_is_held_within_the_known_range_not_the_records_own():
    """The bounded free run of the unstable AR(1) reaches the known range's bound, beyond the record's."""
    y = measured_then_missing()
    prior = (torch.tensor([[UNSTABLE]], dtype=torch.float64), 1e-12)
    known = torch.tensor([[-30.0], [30.0]], dtype=torch.float64)
    got = arx_predict(y, None, 1, 1, prior=prior, bounded=0, known_range=known)[0, :, 0].numpy()
    lo, hi = -30.0, 30.0
    expect = free_run(y[0, :, 0].numpy(), UNSTABLE, lo - 2 * (hi - lo), hi + 2 * (hi - lo))
    np.testing.assert_allclose(got[11:], expect[11:], rtol=1e-9, atol=1e-9)
    assert np.abs(got).max() > 100  # beyond the record's own bounds (its span is under 2)
