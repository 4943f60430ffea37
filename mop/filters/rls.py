"""Recursive least squares matrix autoregression (the paper's RLS baseline), batched over systems.

Order p, outputs y_t in R^m: every output is regressed on all m outputs at p lags,

    yhat_{t+1} = alpha_1 y_t + ... + alpha_p y_{t-p+1} = theta^T phi_t,
    phi_t = [y_t; y_{t-1}; ...; y_{t-p+1}]  (p*m),   theta (p*m, m),  one P (p*m, p*m) per system.

With theta_0 = 0, P_0 = I and forgetting factor 1, after the pairs (phi_{s-1}, y_s), s = p..t-1, theta is the
ridge solution theta = (I + sum phi phi^T)^{-1} sum phi y^T, updated one pair (phi, y) at a time by

    k = P phi / (1 + phi^T P phi),   theta <- theta + k (y - theta^T phi)^T,   P <- P - k phi^T P.

Start-up as the authors' baseline (DESIGN.md): yhat_0 = 0 and yhat_t = y_{t-1} for 1 <= t <= p (for p = 2:
yhat_1 = y_0, yhat_2 = y_1); from t = p + 1 on yhat_t = theta^T phi_{t-1}, theta fitted to the pairs so far.

Missing outputs (NaN in y): a missing regressor entry is replaced by the model's own one-step prediction, and
pairs whose target channel or any regressor was missing are skipped (_rls_run_gaps).
"""

from __future__ import annotations

import torch
from torch import Tensor

from mop.predictors import PREDICTORS, nan_beyond_horizon
from mop.systems.base import Trajectories


def regressors(y: Tensor, order: int) -> Tensor:
    """phi (B, T, p*m): phi[:, t] = [y_t; y_{t-1}; ...; y_{t-p+1}], zero before y_0."""
    padded = torch.cat([y.new_zeros(y.shape[0], order - 1, y.shape[2]), y], dim=1)  # (B, T+p-1, m)
    return torch.cat([padded[:, order - 1 - j : padded.shape[1] - j] for j in range(order)], dim=-1)


def rls_update(theta: Tensor, P: Tensor, phi: Tensor, target: Tensor) -> tuple[Tensor, Tensor]:
    """One RLS step with the pair (phi (B, d), target (B, m)); theta (B, d, m), P (B, d, d)."""
    Pphi = (P @ phi[..., None])[..., 0]  # (B, d)
    k = Pphi / (1 + (phi * Pphi).sum(-1, keepdim=True))  # (B, d)
    err = target - (theta.mT @ phi[..., None])[..., 0]  # (B, m)
    theta = theta + k[..., None] * err[:, None, :]
    P = P - k[..., None] * Pphi[:, None, :]
    return theta, 0.5 * (P + P.mT)


def rls_innovation_update(
    theta: Tensor, P: Tensor, phi: Tensor, target: Tensor
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """rls_update, also returning what the pair told before it was fitted: (theta, P, the prediction error
    target - theta^T phi (B, m), s = 1 + phi^T P phi (B,), the error's variance over the noise's).

    The same recursion in an arithmetic for many small systems at once (a mixture's B K recursions,
    mop.filters.mixture): products as einsum, and P - v v^T with v = P phi / sqrt(s), which keeps a
    symmetric P exactly symmetric with no symmetrising pass; 1.3x faster than rls_update's for 512
    systems of d = 12, equal to rounding."""
    Pphi = torch.einsum("bij,bj->bi", P, phi)  # (B, d)
    s = 1 + (phi * Pphi).sum(-1)  # (B,)
    err = target - torch.einsum("bim,bi->bm", theta, phi)  # (B, m)
    theta = torch.addcmul(theta, (Pphi / s[:, None])[..., None], err[:, None, :])
    v = Pphi * s.rsqrt()[:, None]
    return theta, torch.addcmul(P, v[..., None], v[:, None, :], value=-1), err, s


def _rls_run(y: Tensor, order: int) -> tuple[Tensor, Tensor, dict[int, Tensor]]:
    """(yhat (B, T, m), phi (B, T, p*m), {t: theta (B, d, m) used for yhat_t, t >= p + 1}).

    y with NaN (missing outputs): _rls_run_gaps, phi then built from the filled outputs."""
    if torch.isnan(y).any():
        return _rls_run_gaps(y, order)
    return rls_loop(y, regressors(y, order), order)


# The recursion's starting point: (theta_0 (d, m) or None for 0, P_0), P_0 a number p0 (P_0 = p0 I) or a
# (d, d) matrix
Prior = tuple[Tensor | None, float | Tensor]


def fixed(prior: Prior | None) -> bool:
    """Whether the prior fixes theta at theta_0: P_0 = 0 (a number), so k = 0 and no pair updates it (a
    fixed ARX, model.rls_fixed); the recursions then skip the updates."""
    return prior is not None and not isinstance(prior[1], Tensor) and prior[1] == 0


def initial_state(prior: Prior | None, B: int, d: int, m: int, like: Tensor) -> tuple[Tensor, Tensor]:
    """(theta (B, d, m), P (B, d, d)) at the start of the recursion, in like's dtype and device: theta_0 = 0
    and P_0 = I without a prior; prior: its theta_0 and P_0 (p0 I for a number). With the pairs (phi_s,
    y_{s+1}) theta is then the ridge solution pulled towards theta_0 with weight P_0^-1, i.e. the posterior
    mean under the Gaussian prior theta ~ N(theta_0, sigma^2 P_0) and noise variance sigma^2."""
    eye = torch.eye(d, dtype=like.dtype, device=like.device)
    if prior is None:
        return like.new_zeros(B, d, m), eye.repeat(B, 1, 1)
    theta0, p0 = prior
    P = p0.to(like).expand(B, d, d).clone() if isinstance(p0, Tensor) else p0 * eye.repeat(B, 1, 1)
    theta = like.new_zeros(B, d, m) if theta0 is None else theta0.to(like).expand(B, d, m).clone()
    return theta, P


def rls_loop(
    y: Tensor, phi: Tensor, start: int, prior: Prior | None = None, updates_from: int | None = None
) -> tuple[Tensor, Tensor, dict[int, Tensor]]:
    """The complete-data recursion shared by RLS and ARX: y (B, T, m), regressors phi (B, T, d) with
    phi[:, t] predicting y_{t+1}; yhat_0 = 0, yhat_t = y_{t-1} for 1 <= t <= start, then theta (B, d, m)
    from theta_0, P_0 (initial_state: 0 and I without a prior) and the pairs (phi_{s-1}, y_s), s < t,
    s >= updates_from (default: start; a later one leaves leading rows out of the fit, e.g. a pad of
    assumed values before a record's start). Returns (yhat, phi, {t: theta})."""
    B, T, m = y.shape
    updates_from = start if updates_from is None else updates_from
    theta, P = initial_state(prior, B, phi.shape[-1], m, y)
    preds = [y.new_zeros(B, m)] + [y[:, t - 1] for t in range(1, min(start + 1, T))]
    if fixed(prior) and start + 1 < T:  # P_0 = 0: no pair moves theta; every prediction at once
        later = phi[:, start : T - 1] @ theta  # (B, T - 1 - start, m)
        thetas = dict.fromkeys(range(start + 1, T), theta)
        return torch.cat([torch.stack(preds, dim=1), later], dim=1), phi, thetas
    thetas = {}
    for t in range(start + 1, T):
        if t - 1 >= updates_from:  # the newest pair (phi_{t-2}, y_{t-1})
            theta, P = rls_update(theta, P, phi[:, t - 2], y[:, t - 1])
        thetas[t] = theta
        preds.append((theta.mT @ phi[:, t - 1, :, None])[..., 0])
    return torch.stack(preds, dim=1), phi, thetas


def _rls_run_gaps(
    y: Tensor,
    order: int,
    extra: Tensor | None = None,
    start: int | None = None,
    prior: Prior | None = None,
    updates_from: int | None = None,
    bounded: int | None = None,
    cubes: int = 0,
    known_range: Tensor | None = None,
) -> tuple[Tensor, Tensor, dict[int, Tensor]]:
    """_rls_run for y (B, T, m) with NaN where an output is missing; cubes: the output regressors followed
    by the cubes of the first `cubes` lags (mop.filters.arx.arx_regressors), of the filled outputs alike.

    The regressors use the filled outputs y~_s = y_s where measured, else the model's own one-step
    prediction yhat_s. The pair (phi_{t-2}, y_{t-1}) updates output channel i only when y_{t-1, i} was
    measured and no entry of phi_{t-2} was filled in; so each channel keeps its own P (B, m, d, d) (equal
    to the shared P of rls_update while nothing is missing). Start-up as without gaps: yhat_t = y~_{t-1}
    for 1 <= t <= start (default: order). extra (B, T, e): complete regressors appended to phi_t (ARX's
    input lags [u_t; ...; u_{t-q+1}]). prior: theta_0 and P_0 (initial_state; each channel's P starts at P_0).
    updates_from: no pair with a target y_s, s < updates_from, updates (rls_loop; default: start).
    bounded (None: not bounded): each prediction that reads a filled-in output is held within
    [lo - 2 s, hi + 2 s], lo and hi the channel's least and greatest measured output before it from row
    `bounded` on (rows before it, a fitted start's assumed values, do not count) and s = hi - lo, once the
    channel has 10 of them and s > 0 (fill_bounds). An ARX fitted on a few steps can be unstable, and its
    free run then leaves every range the record has shown (pretrained:wiener-hammerstein simulating a record
    after 50 steps reached 1e13, then NaN); the baselines keep the plain recursion (bounded=None), the
    learned models' features bound it. known_range (2, m): the least and greatest outputs measured before
    the record (fill_bounds).

    Every pair that updates is made of measured values, so the fit is one recursion over regressors built
    in advance (steps where no system updates, a simulated tail, are skipped), and the filling is a second
    loop over only the steps whose prediction reads a filled-in output. The arithmetic of each update is
    rls_update's (the same numbers to the last bit as one loop that built the regressors step by step), in
    half its time: 0.19 against 0.37-0.43 s for ARX(15, 15) with an intercept, 16 systems x 500 steps with
    simulated tails, one thread (cProfile of 40 training steps of class-lti-siso: 0.205 s of a ~0.75 s
    step, where the loop it replaces took 0.43 s).
    """
    B, T, m = y.shape
    start = order if start is None else start
    seen = ~torch.isnan(y)  # (B, T, m)
    measured = torch.where(seen, y, 0)
    missing = (~seen).any(-1).to(y.dtype)  # (B, T)
    # in_phi[:, s]: missing outputs among rows s - order + 1 .. s, the rows phi_s reads
    ends = torch.cumsum(torch.cat([missing.new_zeros(B, 1), missing], 1), 1)  # ends[:, s + 1] = sum_{<= s}
    idx = torch.arange(T, device=y.device)
    in_phi = ends[:, idx + 1] - ends[:, (idx + 1 - order).clamp(min=0)]  # (B, T)
    cubed = lambda lags: lags if not cubes else torch.cat([lags, lags[..., : cubes * m] ** 3], -1)  # noqa: E731
    phi_measured = cubed(regressors(measured, order))
    phi_measured = phi_measured if extra is None else torch.cat([phi_measured, extra], dim=-1)
    # the pair (phi_{s-1}, y_s) updates channel i where y_{s, i} is measured and phi_{s-1} reads no gap
    clean_before = torch.cat([in_phi.new_zeros(B, 1), in_phi[:, :-1]], 1) == 0  # (B, T)
    update = seen & clean_before[..., None]  # (B, T, m)
    if updates_from is not None:
        update[:, :updates_from] = False
    d = phi_measured.shape[-1]
    theta, P = initial_state(prior, B, d, m, y)
    P = P[:, None].repeat(1, m, 1, 1)  # (B, m, d, d)
    frozen = fixed(prior)  # no pair updates: every step's fit is theta_0
    fits = [theta] * max(T - 1 - start, 0) if frozen else []
    for t in range(start + 1, start + 1 if frozen else T):
        phi, upd = phi_measured[:, t - 2], update[:, t - 1]  # the newest pair (phi_{t-2}, y_{t-1})
        every = bool(upd.all())
        if every or bool(upd.any()):
            Pphi = (P @ phi[:, None, :, None])[..., 0]  # (B, m, d)
            k = Pphi / (1 + (phi[:, None] * Pphi).sum(-1, keepdim=True))  # (B, m, d)
            err = measured[:, t - 1] - (theta.mT @ phi[..., None])[..., 0]  # (B, m)
            theta_new = theta + (k * err[..., None]).mT
            P_new = P - k[..., None] * Pphi[..., None, :]
            P_new = 0.5 * (P_new + P_new.mT)
            theta = theta_new if every else torch.where(upd[:, None, :], theta_new, theta)
            P = P_new if every else torch.where(upd[..., None, None], P_new, P)
        fits.append(theta)
    # predictions from the measured regressors, right wherever nothing filled in is read
    preds = torch.cat([y.new_zeros(B, 1, m), measured[:, : min(start, T - 1)]], dim=1)[:, :T]
    if fits and frozen:
        preds = torch.cat([preds, phi_measured[:, start : T - 1] @ theta], dim=1)
    elif fits:
        thetas = torch.stack(fits, dim=1)  # (B, T - 1 - start, d, m): theta_t, t = start + 1 ..
        preds = torch.cat([preds, (thetas.mT @ phi_measured[:, start : T - 1, :, None])[..., 0]], dim=1)
    padded = torch.cat([y.new_zeros(B, order - 1, m), torch.where(seen, y, preds)], 1)  # (B, T+p-1, m)
    filled = padded[:, order - 1 :]  # a view: writing filled writes padded
    # the steps whose prediction reads a filled-in output: y~_{t-1} (t <= start) or phi_{t-1} (t > start)
    reads = torch.where(idx[None, :-1] < start, missing[:, :-1], in_phi[:, :-1])  # for t = 1 .. T-1
    redo = torch.cat([reads.new_zeros(B, 1), reads], 1) > 0  # (B, T)
    low, high = (None, None) if bounded is None else fill_bounds(y, bounded, known_range)
    for t in torch.nonzero(redo.any(0)).flatten().tolist():
        if t <= start:
            pred = filled[:, t - 1]
        else:  # phi_{t-1}: rows t-1, t-2, ..., t-p of the filled outputs
            window = cubed(padded[:, t - 1 : t + order - 1].flip(1).reshape(B, order * m))
            phi = window if extra is None else torch.cat([window, extra[:, t - 1]], dim=-1)
            pred = (fits[t - start - 1].mT @ phi[..., None])[..., 0]
        if low is not None:
            pred = torch.minimum(torch.maximum(pred, low[:, t - 1]), high[:, t - 1])
        preds[:, t] = torch.where(redo[:, t, None], pred, preds[:, t])
        filled[:, t] = torch.where(seen[:, t], y[:, t], preds[:, t])
    phi = cubed(regressors(filled, order))
    phi = phi if extra is None else torch.cat([phi, extra], dim=-1)
    return preds, phi, {t: fits[t - start - 1] for t in range(start + 1, T)}


# fill_bounds' margin on each side, in spans of the measured outputs. Zero-shot class models simulating 200
# held-out systems of their class after 50 steps (mean RMSE; unbounded: 14 of 200 WH and 22 of 200 tank
# simulations above 100 or NaN, up to 1e17): 1 span WH 1.045, tanks 0.971, lti-siso 0.0167; 2 spans 1.223,
# 1.111, 0.0122; 4 spans 1.616, 1.417, 0.0122. At 1 span 14 lti-siso simulations got worse (0.0122
# unbounded); from 2 on none does, and the 200 simulations after 400 steps of each class are unchanged.
FILL_MARGIN = 2.0
# the bounds hold once a channel has this many measured outputs: fewer say little of its range (a record
# simulated from its start has one, a span of 0), and there the free run is left as it is
FILL_MIN_SEEN = 10


def fill_bounds(y: Tensor, first: int = 0, known_range: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """(low, high) (B, T, m) for y (B, T, m) with NaN where missing: lo_t - w s_t and hi_t + w s_t, lo_t and
    hi_t the least and greatest measured y_s, first <= s <= t, per channel, s_t = hi_t - lo_t, w =
    FILL_MARGIN; -inf and inf while the channel has fewer than FILL_MIN_SEEN such outputs or s_t = 0 (a
    record at rest says nothing of its range). known_range (2, m): the least and greatest outputs measured
    before the record (an estimation record read in context), counted as seen from step 0: a test whose
    first outputs span a fraction of the plant's range is otherwise held within a few of their spans (the
    cascaded tanks' fitted ARX, from 50 test outputs near 3.9 V, held at 7.3 V while the level rose to
    10 V)."""
    seen = ~torch.isnan(y)
    seen[:, :first] = False
    hi = torch.where(seen, y, -torch.inf).cummax(dim=1).values
    lo = torch.where(seen, y, torch.inf).cummin(dim=1).values
    count = seen.cumsum(dim=1)
    if known_range is not None:
        known_range = known_range.to(y)
        lo, hi = torch.minimum(lo, known_range[0]), torch.maximum(hi, known_range[1])
        count = count + FILL_MIN_SEEN
    known = (count >= FILL_MIN_SEEN) & (hi > lo)
    span = torch.where(known, FILL_MARGIN * (hi - lo), torch.zeros_like(hi))
    return torch.where(known, lo - span, -torch.inf), torch.where(known, hi + span, torch.inf)


def rls_predict(y: Tensor, order: int = 2) -> Tensor:
    """One-step matrix RLS-AR(order) predictions yhat (B, T, m) for outputs y (B, T, m)."""
    return _rls_run(y, order)[0]


def rls_forecast(y: Tensor, order: int = 2, steps: int = 1) -> Tensor:
    """k-step forecasts (B, T, K, m): from t >= p + 1 the AR recursion fitted to y_{<t} iterated on its own
    predictions, yhat_{t+j} = theta_t^T [yhat_{t+j-1}; ...] (observed y_{t-1}, ... where the regressor reaches
    back before t). During the start-up (t <= p, no regression yet) the one-step prediction (y_{t-1}, 0 at
    t = 0) is repeated for every horizon. j = 0 is rls_predict; entries with t + j >= T are NaN."""
    preds, phi, thetas = _rls_run(y, order)
    m = y.shape[2]
    out = preds[:, :, None].repeat(1, 1, steps, 1)  # (B, T, K, m)
    if thetas:
        ts = sorted(thetas)
        Th = torch.stack([thetas[t] for t in ts], dim=1)  # (B, n_t, d, m)
        ph = phi[:, [t - 1 for t in ts]]  # (B, n_t, d)
        pred = preds[:, ts]  # (B, n_t, m): j = 0 exactly as predicted
        for j in range(1, steps):
            ph = torch.cat([pred, ph[..., :-m]], dim=-1)
            pred = (Th.mT @ ph[..., None])[..., 0]
            out[:, ts, j] = pred
    return nan_beyond_horizon(out)


def adaptive_order_rls_predict(y: Tensor, max_order: int = 5) -> tuple[Tensor, Tensor]:
    """Run matrix RLS of orders 1..max_order; at each t predict with the order whose summed squared one-step
    error over y_{P+1}..y_{t-1} (P = max_order: the steps where every order predicts by regression, so the
    start-up copies do not count) is lowest, per system; ties -> lowest order. Returns yhat (B, T, m),
    order (B, T)."""
    all_preds = torch.stack([rls_predict(y, p) for p in range(1, max_order + 1)], dim=1)  # (B, P, T, m)
    return _best_order(y, all_preds, max_order)


def _best_order(y: Tensor, all_preds: Tensor, max_order: int) -> tuple[Tensor, Tensor]:
    sq = (all_preds - y[:, None]) ** 2  # (B, P, T, m)
    if torch.isnan(y).any():  # score on the measured outputs only
        sq = torch.where(torch.isnan(sq), 0, sq)
    sq_err = sq.sum(-1)  # (B, P, T)
    sq_err[:, :, : max_order + 1] = 0  # score only where every order predicts by regression
    past = torch.cumsum(sq_err, dim=-1) - sq_err  # (B, P, T): errors strictly before t
    best = past.argmin(dim=1)  # (B, T), argmin returns the first (lowest) order on ties
    yhat = torch.gather(all_preds, 1, best[:, None, :, None].expand(-1, 1, -1, y.shape[2]))[:, 0]
    return yhat, best + 1


def adaptive_order_rls_forecast(y: Tensor, max_order: int = 5, steps: int = 1) -> Tensor:
    """k-step forecasts (B, T, K, m) of rls-best: at each t, the rls_forecast of the order chosen at t."""
    fc = torch.stack([rls_forecast(y, p, steps) for p in range(1, max_order + 1)], dim=1)  # (B, P, T, K, m)
    _, order = _best_order(y, fc[:, :, :, 0], max_order)  # (B, T)
    idx = (order - 1)[:, None, :, None, None].expand(-1, 1, -1, *fc.shape[3:])
    return torch.gather(fc, 1, idx)[:, 0]


@PREDICTORS.register("rls", default_panel=True)
class RLSPredictor:
    """Matrix RLS autoregression of a fixed order (the paper's baseline: order 2, 2m regressors)."""

    name = "rls"

    def __init__(self, order: int = 2, name: str = "rls") -> None:
        self.order, self.name = order, name

    def predict(self, traj: Trajectories) -> Tensor:
        return rls_predict(traj.y.double(), self.order).to(traj.y.dtype)

    def forecast(self, traj: Trajectories, steps: int) -> Tensor:
        """(B, T+1, K, m): the fitted AR recursion iterated on its own predictions (see rls_forecast)."""
        return rls_forecast(traj.y.double(), self.order, steps).to(traj.y.dtype)


@PREDICTORS.register("rls-best")
class AdaptiveOrderRLSPredictor:
    """Matrix RLS with the order 1..max_order chosen online by the lowest past one-step error ("rls-best")."""

    name = "rls-best"

    def __init__(self, max_order: int = 5, name: str = "rls-best") -> None:
        self.max_order, self.name = max_order, name

    def predict(self, traj: Trajectories) -> Tensor:
        return adaptive_order_rls_predict(traj.y.double(), self.max_order)[0].to(traj.y.dtype)

    def forecast(self, traj: Trajectories, steps: int) -> Tensor:
        """(B, T+1, K, m): rls_forecast of the order chosen at each t."""
        return adaptive_order_rls_forecast(traj.y.double(), self.max_order, steps).to(traj.y.dtype)
