"""ARX by recursive least squares ("arx", "arx-best"): the output-only RLS baseline (mop.filters.rls) with
past inputs among the regressors, batched over systems, exact (a loop over time only).

Orders p (outputs) and q (inputs), outputs y_t in R^m, inputs u_t in R^k (u_t acts between y_t and y_{t+1}):

    yhat_{t+1} = theta^T phi_t,   phi_t = [y_t; ...; y_{t-p+1}; u_t; ...; u_{t-q+1}]  (p m + q k),
    theta (p m + q k, m), one P per system, zero before y_0 / u_0.

theta_0 = 0, P_0 = I, forgetting 1: after the pairs (phi_{s-1}, y_s), s = r..t-1 (r = max(p, q)), theta is the
ridge solution (I + sum phi phi^T)^{-1} sum phi y^T, updated one pair at a time by mop.filters.rls.rls_update.
Start-up as rls with r in place of p: yhat_0 = 0, yhat_t = y_{t-1} for 1 <= t <= r, then regression.
Without inputs (u None) ARX of order p is rls of order p. Forecasts iterate the fitted model on its own
output predictions with the known future inputs u_t, u_{t+1}, ...

offset=True appends a constant regressor 1 to phi_t (an intercept c: yhat_{t+1} = theta^T phi_t + c, ridge-
penalized like every coefficient). It matters where the outputs carry an offset the dynamics do not explain:
the sysid benchmarks (lti-siso, wiener-hammerstein) subtract each sequence's mean, so y - mean obeys an ARX
equation with the constant mean (1 - sum alpha); "arx-10-offset" fits it (lti-siso, N = 100: one-step RMSE
0.0123 against 0.0214 without, simulation 0.0165 against 0.0868; "arx-15-offset" 0.0118 and 0.0070).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from mop.errors import MopError
from mop.filters.rls import Prior, _best_order, _rls_run_gaps, regressors, rls_loop
from mop.predictors import PREDICTORS, nan_beyond_horizon
from mop.systems.base import Trajectories


def known_regressors(y: Tensor, u: Tensor | None, q: int, offset: bool = False) -> Tensor | None:
    """The regressors known in advance (B, T, q k [+ 1]): the input lags [u_t..u_{t-q+1}] and, with
    offset, a constant 1; None when there are neither."""
    parts = ([] if u is None else [regressors(u, q)]) + ([y.new_ones(*y.shape[:2], 1)] if offset else [])
    return torch.cat(parts, dim=-1) if parts else None


def arx_regressors(
    y: Tensor, u: Tensor | None, p: int, q: int, offset: bool = False, cubes: int = 0
) -> Tensor:
    """phi (B, T, p m + c m + q k [+ 1]): phi[:, t] = [y_t..y_{t-p+1}, y_t^3..y_{t-c+1}^3 (c = cubes),
    u_t..u_{t-q+1}(, 1)], zero before 0."""
    known = known_regressors(y, u, q, offset)
    phi = regressors(y, p)
    if cubes:
        phi = torch.cat([phi, phi[..., : cubes * y.shape[-1]] ** 3], dim=-1)
    return phi if known is None else torch.cat([phi, known], dim=-1)


def least_squares_coefficients(
    records: list[np.ndarray], m: int, p: int, q: int, offset: bool, cubes: int = 0, ridge: float = 1e-6
) -> np.ndarray:
    """theta (d, m) of the ARX(p, q) [with c = cubes cubed output lags, an intercept] by least squares over
    every record (L_i, m + k) (outputs then inputs): the pairs (phi_{s-1}, y_s), s >= max(p, q), phi as
    arx_regressors, the rows the RLS / ARX feature of a model regresses on; a ridge of ridge * (pairs) for
    collinear regressors, or with ridge 0 the minimum-norm least squares (numpy's lstsq, as `mop fit arx`'s
    mop.identify.arx.fit_theta). MopError where an output is missing."""
    r, rows, targets = max(p, q), [], []
    for a in records:
        z = torch.from_numpy(np.asarray(a, dtype=np.float64))[None]  # (1, L, m + k)
        u = z[..., m:] if q > 0 else None
        phi = arx_regressors(z[..., :m], u, p, max(q, 1), offset, cubes)[0]  # (L, d)
        rows.append(phi[r - 1 : -1])
        targets.append(z[0, r:, :m])
    phi, target = torch.cat(rows).numpy(), torch.cat(targets).numpy()
    if np.isnan(target).any():
        raise MopError("a least-squares ARX fit needs complete outputs; fill the gaps")
    if ridge == 0:
        return np.linalg.lstsq(phi, target, rcond=None)[0]
    gram = phi.T @ phi + ridge * len(phi) * np.eye(phi.shape[1])
    return np.linalg.solve(gram, phi.T @ target)


def _arx_run(
    y: Tensor,
    u: Tensor | None,
    p: int,
    q: int,
    offset: bool = False,
    prior: Prior | None = None,
    updates_from: int | None = None,
    bounded: int | None = None,
    cubes: int = 0,
    known_range: Tensor | None = None,
) -> tuple[Tensor, Tensor, dict[int, Tensor]]:
    """(yhat (B, T, m), phi (B, T, d), {t: theta (B, d, m) used for yhat_t, t >= r + 1}).

    y with NaN (missing outputs): mop.filters.rls._rls_run_gaps with the input lags (and the constant) as
    complete extra regressors, so pairs with a missing target or output regressor are skipped and missing
    regressors are filled with the model's own one-step predictions (phi then holds the filled outputs).
    prior: (theta_0 (d, m), P_0) for the recursion (rls_loop, _rls_run_gaps); updates_from: the first target
    index whose pair updates the fit (rls_loop; default r); bounded: the filled-in outputs held within the
    range of the measured ones from row `bounded` on, widened by twice its span (_rls_run_gaps); cubes: the
    cubes of the first `cubes` output lags as regressors too (arx_regressors; of the filled outputs where
    some are missing)."""
    r = p if u is None else max(p, q)
    if torch.isnan(y).any():
        extra = known_regressors(y, u, q, offset)
        return _rls_run_gaps(y, p, extra, r, prior, updates_from, bounded, cubes, known_range)
    return rls_loop(y, arx_regressors(y, u, p, q, offset, cubes), r, prior, updates_from)


def arx_predict(
    y: Tensor,
    u: Tensor | None,
    p: int = 2,
    q: int = 2,
    offset: bool = False,
    prior: Prior | None = None,
    updates_from: int | None = None,
    bounded: int | None = None,
    cubes: int = 0,
    known_range: Tensor | None = None,
) -> Tensor:
    """One-step ARX(p, q) predictions yhat (B, T, m) for y (B, T, m), u (B, T, k) or None; offset: with a
    constant regressor (an intercept); prior: theta_0 (d, m) and P_0 of the recursion (rls_loop);
    updates_from: the first target index whose pair updates the fit (default max(p, q)); bounded (a row
    index, None: not bounded): where outputs are missing, the predictions that read filled-in ones are held
    within the range of the outputs measured from that row on, widened by twice its span
    (mop.filters.rls._rls_run_gaps); cubes: with the cubes of the first `cubes` output lags
    (arx_regressors); known_range (2, m): the outputs' range measured before the record, within which the
    bounded predictions are held too (mop.filters.rls.fill_bounds)."""
    return _arx_run(y, u, p, q, offset, prior, updates_from, bounded, cubes, known_range)[0]


def arx_forecast(
    y: Tensor,
    u: Tensor | None,
    p: int = 2,
    q: int = 2,
    steps: int = 1,
    origin: int | None = None,
    offset: bool = False,
    prior: Prior | None = None,
) -> Tensor:
    """k-step forecasts (B, T, K, m): from t >= r + 1 the model fitted to y_{<t} iterated on its own
    predictions, yhat_{t+j} = theta_t^T [yhat_{t+j-1}; ...; u_{t+j-1}; ...] (observed y where the regressor
    reaches back before t, the known inputs u_{t+j-1}..). During the start-up the one-step prediction is
    repeated. j = 0 is arx_predict; entries with t + j >= T are NaN. origin: roll out from that t only (the
    other origins keep the one-step prediction repeated): what free-run simulation needs. prior: the
    recursion's theta_0 and P_0 (rls_loop)."""
    if origin is None:
        preds, phi, thetas = _arx_run(y, u, p, q, offset, prior)
    else:  # fit on y_0..y_origin only; the regressors' input lags come from the full u
        cut = slice(0, origin + 1)
        preds, _, thetas = _arx_run(y[:, cut], None if u is None else u[:, cut], p, q, offset, prior)
        thetas = {t: th for t, th in thetas.items() if t == origin}
        preds = torch.cat([preds, y.new_zeros(y.shape[0], y.shape[1] - preds.shape[1], y.shape[2])], dim=1)
        phi = arx_regressors(y, u, p, q, offset)
    B, T, m = y.shape
    out = preds[:, :, None].repeat(1, 1, steps, 1)  # (B, T, K, m)
    if not thetas:
        return nan_beyond_horizon(out)
    ts = sorted(thetas)
    Th = torch.stack([thetas[t] for t in ts], dim=1)  # (B, n_t, d, m)
    ph = phi[:, [t - 1 for t in ts]]  # (B, n_t, d)
    pred = preds[:, ts]  # (B, n_t, m)
    py = p * m
    for j in range(1, steps):
        ph_y = torch.cat([pred, ph[..., : py - m]], dim=-1)  # output lags shifted by one
        if phi.shape[-1] == py:
            ph = ph_y
        else:
            idx = torch.tensor([min(t - 1 + j, T - 1) for t in ts], device=y.device)  # regressor time
            ph = torch.cat([ph_y, phi[:, idx, py:]], dim=-1)  # input lags (and the constant) are known
        pred = (Th.mT @ ph[..., None])[..., 0]
        out[:, ts, j] = pred
    return nan_beyond_horizon(out)


def _orders(max_order: int) -> range:
    if max_order < 1:
        raise MopError(f"arx-best: max_order must be >= 1, got {max_order}")
    return range(1, max_order + 1)


def adaptive_order_arx_predict(y: Tensor, u: Tensor | None, max_order: int = 5) -> tuple[Tensor, Tensor]:
    """ARX(p, p) for p = 1..max_order; at each t the order with the lowest summed squared one-step error over
    y_{P+1}..y_{t-1} (P = max_order), per system, ties -> lowest (as rls-best).
    Returns (yhat (B, T, m), order (B, T))."""
    preds = torch.stack([arx_predict(y, u, p, p) for p in _orders(max_order)], dim=1)  # (B, P, T, m)
    return _best_order(y, preds, max_order)


def adaptive_order_arx_forecast(y: Tensor, u: Tensor | None, max_order: int = 5, steps: int = 1) -> Tensor:
    """k-step forecasts (B, T, K, m) of arx-best: at each t, the arx_forecast of the order chosen at t."""
    fc = torch.stack([arx_forecast(y, u, p, p, steps) for p in _orders(max_order)], dim=1)  # (B, P, T, K, m)
    _, order = _best_order(y, fc[:, :, :, 0], max_order)  # (B, T)
    idx = (order - 1)[:, None, :, None, None].expand(-1, 1, -1, *fc.shape[3:])
    return torch.gather(fc, 1, idx)[:, 0]


def _u(traj: Trajectories) -> Tensor | None:
    return None if traj.u is None else traj.u.double()


@PREDICTORS.register("arx")
class ARXPredictor:
    """ARX(p, q) by RLS on [y_t..y_{t-p+1}, u_t..u_{t-q+1}] (rls of order p where there are no inputs);
    offset: with a constant regressor; p0: the recursion's P_0 = p0 I (1: the paper's RLS; larger: closer
    to least squares)."""

    def __init__(
        self,
        order: int = 2,
        input_order: int | None = None,
        offset: bool = False,
        name: str = "arx",
        p0: float = 1.0,
    ) -> None:
        self.order, self.input_order, self.name = order, order if input_order is None else input_order, name
        self.offset, self.p0 = offset, p0
        if self.order < 1 or self.input_order < 1:
            raise MopError(f"arx: orders must be >= 1, got p={self.order}, q={self.input_order}")
        if p0 <= 0:
            raise MopError(f"arx: p0 must be > 0 (P_0 = p0 I), got {p0}")

    @property
    def _prior(self) -> Prior | None:
        """(theta_0 = 0, p0) for the recursion, None for the paper's P_0 = I."""
        return None if self.p0 == 1.0 else (None, self.p0)

    def predict(self, traj: Trajectories) -> Tensor:
        p, q = self.order, self.input_order
        out = arx_predict(traj.y.double(), _u(traj), p, q, self.offset, self._prior)
        return out.to(traj.y.dtype)

    def forecast(self, traj: Trajectories, steps: int) -> Tensor:
        """(B, T+1, K, m): the fitted ARX iterated on its predictions with the known inputs."""
        p, q, prior = self.order, self.input_order, self._prior
        out = arx_forecast(traj.y.double(), _u(traj), p, q, steps, offset=self.offset, prior=prior)
        return out.to(traj.y.dtype)

    def simulate(self, traj: Trajectories, context: int) -> Tensor:
        """(B, T+1-c, m): forecast[:, c] alone (the model fitted to y_<c, rolled out with the inputs)."""
        steps, p, q, prior = traj.horizon + 1 - context, self.order, self.input_order, self._prior
        out = arx_forecast(traj.y.double(), _u(traj), p, q, steps, context, self.offset, prior)
        return out[:, context].to(traj.y.dtype)


@PREDICTORS.register("arx-best")
class AdaptiveOrderARXPredictor:
    """ARX(p, p) with p = 1..max_order chosen online by the lowest past one-step error ("arx-best")."""

    def __init__(self, max_order: int = 5, name: str = "arx-best") -> None:
        _orders(max_order)
        self.max_order, self.name = max_order, name

    def predict(self, traj: Trajectories) -> Tensor:
        return adaptive_order_arx_predict(traj.y.double(), _u(traj), self.max_order)[0].to(traj.y.dtype)

    def forecast(self, traj: Trajectories, steps: int) -> Tensor:
        """(B, T+1, K, m): arx_forecast of the order chosen at each t."""
        out = adaptive_order_arx_forecast(traj.y.double(), _u(traj), self.max_order, steps)
        return out.to(traj.y.dtype)


PREDICTORS.add("arx-10", lambda: ARXPredictor(10, name="arx-10"))  # orders of the lti-siso class: 1..10
# the sysid benchmarks' per-sequence mean removal leaves a constant in the ARX equation
PREDICTORS.add("arx-10-offset", lambda: ARXPredictor(10, offset=True, name="arx-10-offset"))
PREDICTORS.add("arx-15-offset", lambda: ARXPredictor(15, offset=True, name="arx-15-offset"))
# the same by least squares (P_0 = 1e4 I: the ridge 1e-4 against ~400 unit-scale pairs), what class-lti-siso
# reads: on noise-free records the paper's P_0 = I is what limits it (lti-siso, 200 systems, record frame:
# one-step RMSE over t >= 50 0.0127 -> 0.00011, simulation of y_400..y_499 0.0100 -> 0.0006)
PREDICTORS.add("arx-15-offset-ls", lambda: ARXPredictor(15, offset=True, name="arx-15-offset-ls", p0=1e4))
PREDICTORS.add("arx-10-offset-ls", lambda: ARXPredictor(10, offset=True, name="arx-10-offset-ls", p0=1e4))


class NARXPredictor(ARXPredictor):
    """The ARX(p, q) with an intercept and the cubes of its first c output lags (the cubic NARX the class
    model of the duffing family reads, mop.filters.arx.arx_regressors), by RLS from P_0 = p0 I in the
    record's own units. It simulates by reading the outputs after the context as missing (the recursion's
    gap path, mop.filters.rls._rls_run_gaps: its own predictions fed back, held within twice the measured
    range), and forecasts the same way from every origin."""

    def __init__(self, order: int, cubes: int, name: str, p0: float = 1e4) -> None:
        super().__init__(order, offset=True, name=name, p0=p0)
        if not 0 < cubes <= order:
            raise MopError(f"narx: cubes must be in [1, p = {order}], got {cubes}")
        self.cubes = cubes

    def predict(self, traj: Trajectories) -> Tensor:
        p, q = self.order, self.input_order
        return arx_predict(traj.y.double(), _u(traj), p, q, True, self._prior, cubes=self.cubes).to(
            traj.y.dtype
        )

    def _free_run(self, traj: Trajectories, origin: int, end: int) -> Tensor:
        """(B, end - origin, m): y_origin..y_{end-1} predicted from y_<origin with the outputs from origin on
        read as missing (the recursion's own predictions fed back, bounded), in float64."""
        y = traj.y[:, :end].double().clone()
        y[:, origin:] = float("nan")
        u = _u(traj)
        part = None if u is None else u[:, :end]
        p, q = self.order, self.input_order
        return arx_predict(y, part, p, q, True, self._prior, bounded=0, cubes=self.cubes)[:, origin:]

    def forecast(self, traj: Trajectories, steps: int, start: int = 0) -> Tensor:
        """(B, T+1, K, m): from each origin t >= start, _free_run over y_t..y_{t+K-1} (one recursion per
        origin); NaN for origins before start."""
        B, T1, m = traj.y.shape
        out = traj.y.new_full((B, T1, steps, m), float("nan"), dtype=torch.float64)
        for t in range(start, T1):
            end = min(t + steps, T1)
            out[:, t, : end - t] = self._free_run(traj, t, end)
        return out.to(traj.y.dtype)

    def simulate(self, traj: Trajectories, context: int) -> Tensor:
        """(B, T+1-c, m): _free_run from the context c to the record's end."""
        return self._free_run(traj, context, traj.y.shape[1]).to(traj.y.dtype)


PREDICTORS.add("narx-10-cubes-10-offset-ls", lambda: NARXPredictor(10, 10, "narx-10-cubes-10-offset-ls"))
