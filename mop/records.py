"""A predictor applied to a user's records (trajectories of unequal lengths), and the identification field's
figures of merit.

Data: [(y (T_i+1, m), u (T_i+1, k) | None)] as mop.io.read_trajectories returns it.
Time convention (every mop predictor): yhat_t predicts y_t from y_<t and u_<t; forecast[t, j] predicts
y_{t+j} from y_<t and u_<t+j; a simulation after a context of C outputs predicts y_C..y_T from y_0..y_{C-1}
and the inputs alone.

Figures of merit over the scored steps (missing outputs, NaN in y, left out), per output channel and then
averaged over the channels:
    RMSE = sqrt(mean_t (y_t - yhat_t)^2)                       (in the record's units)
    NRMSE = RMSE / std_t(y_t)                                   (the nonlinear-benchmark convention)
    fit = 100 (1 - ||y - yhat|| / ||y - mean y||)  [%]          (MATLAB's `compare`; 100 is perfect)
(NRMSE = 1 - fit / 100 channel by channel; both are printed because both are quoted.)
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import torch

from mop.predictors import forecast, nan_beyond_horizon, simulate
from mop.systems.base import SystemParams, Trajectories

Data = list[tuple[np.ndarray, np.ndarray | None]]
BATCH_SIZE = 256  # trajectories per padded batch of unequal lengths


def batches(data: Data, family: str, params: SystemParams | None) -> list[tuple[list[int], Trajectories]]:
    """(indices into data, Trajectories) batches. All trajectories at once when they share a length (with
    the system's parameters); otherwise sorted by length, BATCH_SIZE at a time, each padded at the end to
    the longest of its batch by repeating its last row. Every predictor is causal (yhat_t reads y_<t, u_<t;
    forecast[t, j] reads y_<t, u_<t+j), so the entries kept (t <= T_i) never read the padding."""
    lengths = [len(y) for y, _ in data]
    if len(set(lengths)) == 1:
        return [(list(range(len(data))), _stack(data, list(range(len(data))), lengths[0], family, params))]
    order = sorted(range(len(data)), key=lambda i: lengths[i])
    out = []
    for start in range(0, len(order), BATCH_SIZE):
        idx = order[start : start + BATCH_SIZE]
        rows = None if params is None else params.select(idx)
        out.append((idx, _stack(data, idx, lengths[idx[-1]], family, rows)))
    return out


def _stack(data: Data, idx: list[int], length: int, family: str, params: SystemParams | None) -> Trajectories:
    """The trajectories `idx` of data, each padded to `length` steps, as float32 Trajectories."""
    y = torch.tensor(np.stack([_pad(data[i][0], length) for i in idx]), dtype=torch.float32)
    u = None
    if data[idx[0]][1] is not None:
        u = torch.tensor(np.stack([_pad(data[i][1], length) for i in idx]), dtype=torch.float32)
    return Trajectories(y=y, u=u, params=params, family=family)


def _pad(a: np.ndarray, length: int) -> np.ndarray:
    """(T_i+1, c) -> (length, c): the last row repeated."""
    return np.concatenate([a, np.repeat(a[-1:], length - len(a), axis=0)])


def predict_all(predictor, data: Data, steps: int | None = None, family: str = "", params=None) -> list:
    """[(T_i+1, m)] predictions (or [(T_i+1, K, m)] forecasts with steps, NaN where t + j > T_i), in the
    order of data, computed in batches (see batches)."""
    out: list[np.ndarray | None] = [None] * len(data)
    for idx, traj in batches(data, family, params):
        pred = predictor.predict(traj) if steps is None else forecast(predictor, traj, steps)
        pred = pred.double().cpu()
        for row, i in enumerate(idx):
            own = pred[row : row + 1, : len(data[i][0])].clone()  # (1, T_i+1, ...)
            out[i] = (own if steps is None else nan_beyond_horizon(own))[0].numpy()
    return out


def simulate_all(predictor, data: Data, context: int, family: str = "", params=None) -> list[np.ndarray]:
    """[(T_i+1-C, m)] free-run simulations after C outputs, in the order of data, computed in batches (see
    batches: sim[:, j] predicts y_{C+j} from y_<C and u_<C+j, so the kept j <= T_i - C never read padding).
    A simulation reads no output after its context, so a missing one there (NaN) is no reason to refuse; it
    is left out of the score (simulation_rmse)."""
    out: list[np.ndarray | None] = [None] * len(data)
    for idx, traj in batches(data, family, params):
        sim = simulate(predictor, traj, context).double().cpu().numpy()
        for row, i in enumerate(idx):
            out[i] = sim[row, : len(data[i][0]) - context]
    return out


DIVERGENCE_FACTOR = 100.0  # a simulation farther than this many output ranges from them has diverged


def divergence_step(y: np.ndarray, sim: np.ndarray, factor: float = DIVERGENCE_FACTOR) -> int | None:
    """The first row j of a free-run simulation sim (T', m) that is non-finite or farther than `factor`
    (DIVERGENCE_FACTOR) times the measured range of y (T, m) outside that range, per channel; None where
    it stays. A diverged simulation is scored as diverged (RMSE inf), never over its finite steps."""
    with np.errstate(invalid="ignore"):
        lo, hi = np.nanmin(y, axis=0), np.nanmax(y, axis=0)  # (m,)
        span = np.maximum(hi - lo, np.finfo(float).tiny)
        bad = ~np.isfinite(sim) | (sim < lo - factor * span) | (sim > hi + factor * span)
    rows = np.flatnonzero(bad.any(axis=-1))
    return int(rows[0]) if len(rows) else None


def simulation_rmse(y: np.ndarray, sim: np.ndarray) -> tuple[float, int | None]:
    """(RMSE, None) of a free run sim (T', m) against the last T' rows of the record y (T, m), missing
    outputs left out; (inf, j) where it diverged at its row j (divergence_step against all of y)."""
    step = divergence_step(y, sim)
    if step is not None:
        return float("inf"), step
    return float(np.sqrt(np.nanmean((y[len(y) - len(sim) :] - sim) ** 2))), None


def observed_norms(e: np.ndarray) -> np.ndarray:
    """||e_t|| over the measured channels (e NaN where y was missing) for the steps with any measured:
    e (T, m) -> (T',)."""
    seen = ~np.isnan(e).all(axis=-1)
    return np.sqrt(np.nansum(e[seen] ** 2, axis=-1))


@dataclasses.dataclass(frozen=True)
class Scores:
    """Figures of merit of predictions of one or more records (see the module docstring)."""

    steps: int  # scored time steps
    rmse: float
    nrmse: float
    fit: float  # percent
    mean_norm: float  # mean over the scored steps of ||y_t - yhat_t|| over the measured channels


def scores(y: list[np.ndarray] | np.ndarray, yhat: list[np.ndarray] | np.ndarray) -> Scores:
    """Scores of predictions yhat of y: arrays (T, m) or lists of them, pooled over the list (NaN in y:
    missing, left out; a channel constant over the scored steps has NRMSE and fit NaN)."""
    y = np.concatenate(y) if isinstance(y, list) else y
    yhat = np.concatenate(yhat) if isinstance(yhat, list) else yhat
    e = y - yhat  # (T, m)
    with warnings.catch_warnings():  # no prediction at all (a blank column) scores NaN, without a warning
        warnings.simplefilter("ignore", RuntimeWarning)
        rmse = np.sqrt(np.nanmean(e**2, axis=0))  # (m,)
        spread = np.sqrt(np.nanmean((y - np.nanmean(y, axis=0)) ** 2, axis=0))  # (m,) population std
        total = float(np.sqrt(np.nanmean(e**2)))
    with np.errstate(divide="ignore", invalid="ignore"):
        nrmse = np.where(spread > 0, rmse / spread, np.nan)
    norms = observed_norms(e)
    return Scores(
        steps=len(norms),
        rmse=total,
        nrmse=float(np.mean(nrmse)),
        fit=float(100 * (1 - np.mean(nrmse))),
        mean_norm=float(norms.mean()) if len(norms) else float("nan"),
    )
