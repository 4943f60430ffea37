"""Subspace identification (N4SID-style: stochastic from outputs alone, combined deterministic-stochastic
where there are inputs) and the Kalman predictor of the identified model, batched over systems with torch.

From outputs y_0..y_{N-1} (B, N, m) and i block rows:
    H = block Hankel of y with 2i block rows and j = N - 2i + 1 columns,  Y_p = H[:im], Y_f = H[im:]
    O = Y_f / Y_p = Y_f Y_p^T (Y_p Y_p^T)^{-1} Y_p             (orthogonal projection onto the past)
    O = U S V^T,  X = S_n^{1/2} V_n^T                           (Kalman state sequence, times i..N-i; order n)
    [X_{+}; Y] = [A; C] X_{-}  (least squares), residuals W, E  ->  K = W E^T (E E^T)^{-1}
giving the innovation model x_{t+1} = A x_t + K e_t, y_t = C x_t + e_t, whose steady-state predictor is
    yhat_t = C m_t,  m_{t+1} = A m_t + K (y_t - C m_t),  m_0 = 0.

With inputs u (B, N, k) (identify_with_inputs; u_t acts between y_t and y_{t+1}, so no direct term D):
    W_p = [U_p; Y_p],  Y_f = L_w W_p + L_u U_f (least squares),  O = L_w W_p      (oblique projection)
    O = U S V^T,  X = S_n^{1/2} V_n^T;   [X_+] = [A B] [X_-; U],  Y = C X_-;  K from the residuals as above,
and the predictor m_{t+1} = A m_t + B u_t + K (y_t - C m_t). Tested against nfoursid (PO-MOESP) by the
Markov parameters C A^j B it identifies.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import torch
from torch import Tensor

from mop.errors import MopError, MopWarning
from mop.filters.arx import arx_forecast
from mop.filters.rls import rls_forecast
from mop.predictors import PREDICTORS, nan_beyond_horizon
from mop.systems.base import Trajectories


def block_hankel(y: Tensor, num_block_rows: int) -> Tensor:
    """(B, num_block_rows * m, N - num_block_rows + 1): block row k holds y_{k}, y_{k+1}, ... as columns."""
    B, N, m = y.shape
    windows = y.unfold(1, num_block_rows, 1)  # (B, j, m, rows)
    return windows.permute(0, 3, 2, 1).reshape(B, num_block_rows * m, N - num_block_rows + 1).contiguous()


def _lstsq_right(Y: Tensor, X: Tensor, ridge: float) -> Tensor:
    """Theta (B, p, q) minimizing ||Y - Theta X||^2 + ridge ||Theta||^2 for Y (B, p, j), X (B, q, j)."""
    X, Y = X.contiguous(), Y.contiguous()
    G = X @ X.mT + ridge * torch.eye(X.shape[1], dtype=X.dtype, device=X.device)  # (B, q, q)
    return torch.linalg.solve(G, X @ Y.mT).mT


def identify(
    y: Tensor, order: int, num_block_rows: int, ridge: float = 1e-8
) -> tuple[Tensor, Tensor, Tensor]:
    """(A (B, n, n), C (B, m, n), K (B, n, m)) of an order-n innovation model fitted to y (B, N, m)."""
    B, N, m = y.shape
    i = num_block_rows
    if i * m < order or N - 2 * i + 1 < order + 2:
        raise MopError(
            f"subspace: {N} outputs with {i} block rows cannot identify order {order}; use more data"
        )
    H = block_hankel(y, 2 * i)  # (B, 2im, j)
    Yp, Yf = H[:, : i * m], H[:, i * m :]
    scale = Yp.shape[-1]
    O = _lstsq_right(Yf, Yp, ridge * scale) @ Yp  # (B, im, j)
    U, S, Vh = torch.linalg.svd(O, full_matrices=False)
    X = S[:, :order, None].sqrt() * Vh[:, :order]  # (B, n, j)
    Y = y[:, i : i + X.shape[-1] - 1].mT  # (B, m, j-1): outputs at the times of X[..., :-1]
    AC = _lstsq_right(torch.cat([X[..., 1:], Y], dim=1), X[..., :-1], ridge * scale)  # (B, n+m, n)
    A, C = AC[:, :order], AC[:, order:]
    W = X[..., 1:] - A @ X[..., :-1]  # (B, n, j-1)
    E = Y - C @ X[..., :-1]  # (B, m, j-1)
    K = _lstsq_right(W, E, ridge * scale)  # (B, n, m)
    return A, C, K


def identify_with_inputs(
    y: Tensor, u: Tensor, order: int, num_block_rows: int, ridge: float = 1e-8
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """(A (B, n, n), B (B, n, k), C (B, m, n), K (B, n, m)) of an order-n innovation model with inputs,
    x_{t+1} = A x_t + B u_t + K e_t, y_t = C x_t + e_t, fitted to y (B, N, m), u (B, N, k)."""
    batch, N, m = y.shape
    k, i = u.shape[-1], num_block_rows
    if i * m < order or N - 2 * i + 1 < order + k + 2:
        raise MopError(
            f"subspace: {N} outputs with {i} block rows cannot identify order {order}; use more data"
        )
    Hy, Hu = block_hankel(y, 2 * i), block_hankel(u, 2 * i)  # (B, 2im, j), (B, 2ik, j)
    Wp = torch.cat([Hu[:, : i * k], Hy[:, : i * m]], dim=1)  # (B, i(k+m), j)
    Uf, Yf = Hu[:, i * k :], Hy[:, i * m :]
    scale = Wp.shape[-1]
    L = _lstsq_right(Yf, torch.cat([Wp, Uf], dim=1), ridge * scale)  # (B, im, i(k+m) + ik)
    O = L[..., : Wp.shape[1]] @ Wp  # (B, im, j): Y_f projected obliquely onto W_p along U_f
    _, S, Vh = torch.linalg.svd(O, full_matrices=False)
    X = S[:, :order, None].sqrt() * Vh[:, :order]  # (B, n, j): states at times i..i+j-1
    Y = y[:, i : i + X.shape[-1] - 1].mT  # (B, m, j-1)
    U = u[:, i : i + X.shape[-1] - 1].mT  # (B, k, j-1)
    AB = _lstsq_right(X[..., 1:], torch.cat([X[..., :-1], U], dim=1), ridge * scale)  # (B, n, n+k)
    A, Bm = AB[..., :order], AB[..., order:]
    C = _lstsq_right(Y, X[..., :-1], ridge * scale)  # (B, m, n)
    W = X[..., 1:] - AB @ torch.cat([X[..., :-1], U], dim=1)  # (B, n, j-1)
    E = Y - C @ X[..., :-1]  # (B, m, j-1)
    K = _lstsq_right(W, E, ridge * scale)  # (B, n, m)
    return A, Bm, C, K


def _run_predictor(
    A: Tensor, C: Tensor, K: Tensor, y: Tensor, Bm: Tensor | None = None, u: Tensor | None = None
) -> Tensor:
    """State m_N (B, n) of the innovation predictor after reading y (B, N, m) (and u), from m_0 = 0."""
    m = y.new_zeros(A.shape[0], A.shape[-1])
    F = A - K @ C  # (B, n, n)
    for t in range(y.shape[1]):
        m = (F @ m[..., None] + K @ y[:, t, :, None])[..., 0]
        if Bm is not None:
            m = m + (Bm @ u[:, t, :, None])[..., 0]
    return m


def n4sid_kalman_predict(
    y: Tensor,
    order: int = 4,
    num_block_rows: int | None = None,
    min_prefix: int = 20,
    every: int = 1,
    min_columns: int | None = None,
    select: bool = True,
    u: Tensor | None = None,
) -> Tensor:
    """yhat (B, T, m): for t >= t_0, re-identify (A, C, K) from y_0..y_{t-1} every `every` steps and predict
    y_t with its steady-state predictor (state recomputed over the prefix after each re-identification,
    carried forward between them); before t_0 the RLS-AR(2) prediction. With inputs u (B, T, k): the model
    with inputs (identify_with_inputs), ARX(2, 2) in place of RLS-AR(2), and min_columns 2 i (m + k).

    t_0 = max(min_prefix, 2 i - 1 + min_columns): the prefix must give the Hankel matrix (2 i m rows) at least
    min_columns columns (default 2 i m): with fewer, the projection Y_f / Y_p (i m regressors) fits the noise
    and the residual-based K is meaningless, which made the first identifications (t ~ 20, 17 columns for
    20 rows) far worse than RLS. Systems whose identified predictor A - K C is unstable use RLS.
    select: per system, use the identified predictor at t only if its out-of-sample one-step squared errors
    over t_0..t-1 sum below RLS's over the same steps (causal; ties -> RLS), as rls-best chooses its order.
    """
    args = (order, num_block_rows, min_prefix, every, min_columns, select, u)
    return n4sid_kalman_forecast(y, 1, *args)[:, :, 0]


def n4sid_kalman_forecast(
    y: Tensor,
    steps: int,
    order: int = 4,
    num_block_rows: int | None = None,
    min_prefix: int = 20,
    every: int = 1,
    min_columns: int | None = None,
    select: bool = True,
    u: Tensor | None = None,
    origin: int | None = None,
) -> Tensor:
    """k-step forecasts (B, T, K, m) of n4sid_kalman_run (see there)."""
    args = (order, num_block_rows, min_prefix, every, min_columns, select, u, origin)
    return n4sid_kalman_run(y, steps, *args)[0]


def n4sid_kalman_run(
    y: Tensor,
    steps: int,
    order: int = 4,
    num_block_rows: int | None = None,
    min_prefix: int = 20,
    every: int = 1,
    min_columns: int | None = None,
    select: bool = True,
    u: Tensor | None = None,
    origin: int | None = None,
) -> tuple[Tensor, Tensor, int]:
    """(forecasts (B, T, K, m), used (B, T) bool, t_0). used[:, t]: the identified model made yhat_t (and
    the forecasts from t); False where the fallback did: before t_0 (the start-up) and where the model was
    unstable or had not beaten the fallback (select). Forecasts: where n4sid_kalman_predict uses the
    identified model at t, its state m_t is propagated with no measurement, yhat_{t+j} = C A^j m_t (with
    inputs: m <- A m + B u, the known future inputs); where it uses RLS-AR(2) (ARX(2, 2)), that model's
    iterated recursion. j = 0 is n4sid_kalman_predict; entries with t + j >= T are NaN. origin: roll out
    only from that t (one-step predictions elsewhere; what free-run simulation needs), and stop there."""
    B, T, m = y.shape
    k = 0 if u is None else u.shape[-1]
    i = num_block_rows or max(2, math.ceil(order / m) + 1)
    min_columns = 2 * i * (m + k) if min_columns is None else min_columns
    start = max(min_prefix, 2 * i - 1 + min_columns, 2 * i - 1 + order + k + 2)
    if u is None:
        fallback_k = rls_forecast(y, 2, steps)  # (B, T, K, m)
    else:
        fallback_k = arx_forecast(y, u, 2, 2, steps, origin)
    fallback = fallback_k[:, :, 0]  # (B, T, m) = rls_predict(y, 2) (arx_predict(y, u, 2, 2))
    out, used = fallback_k.clone(), torch.zeros(B, T, dtype=torch.bool, device=y.device)
    fit = None
    score = y.new_zeros(B)  # sum over past steps of (model error^2 - RLS error^2)
    for t in range(start, T if origin is None else min(origin + 1, T)):
        if (t - start) % every == 0:
            fit = Identified.from_prefix(y, u, t, order, i)
        kf = (fit.C @ fit.state[..., None])[..., 0]  # (B, m)
        model = torch.where(fit.stable[:, None], kf, fallback[:, t])
        use = score < 0 if select else torch.ones_like(fit.stable)
        out[:, t, 0] = torch.where(use[:, None], model, fallback[:, t])
        used[:, t] = use & fit.stable
        if origin in (None, t):
            fit.roll_out(u, t, min(steps, T - t), (use & fit.stable)[:, None], fallback_k, out)
        score = score + ((model - y[:, t]) ** 2).sum(-1) - ((fallback[:, t] - y[:, t]) ** 2).sum(-1)
        fit.update(y[:, t], kf, None if u is None else u[:, t])
    return nan_beyond_horizon(out), used, start


@dataclass
class Identified:
    """The innovation model identified from y_<t (A (B, n, n), C (B, m, n), K (B, n, m), B (B, n, k) or
    None), whether its predictor A - K C is stable (B,), and its predictor state m_t (B, n)."""

    A: Tensor
    B: Tensor | None
    C: Tensor
    K: Tensor
    stable: Tensor
    state: Tensor

    @classmethod
    def from_prefix(cls, y: Tensor, u: Tensor | None, t: int, order: int, i: int) -> Identified:
        """Identify from y_0..y_{t-1} (and u_0..u_{t-1}) and run its predictor to m_t."""
        if u is None:
            (A, C, K), Bm = identify(y[:, :t], order, i), None
        else:
            A, Bm, C, K = identify_with_inputs(y[:, :t], u[:, :t], order, i)
        stable = torch.linalg.eigvals(A - K @ C).abs().amax(-1) < 1  # (B,) usable predictor
        state = _run_predictor(A, C, K, y[:, :t], Bm, None if u is None else u[:, :t])
        return cls(A, Bm, C, K, stable, state)

    def roll_out(
        self, u: Tensor | None, t: int, steps: int, use: Tensor, fallback_k: Tensor, out: Tensor
    ) -> None:
        """out[:, t, j] = C A^j m_t (with the known inputs), j = 1..steps-1, where `use` (B, 1), else the
        fallback's forecast fallback_k[:, t, j]."""
        ahead = self.state
        for j in range(1, steps):
            ahead = (self.A @ ahead[..., None])[..., 0]
            if self.B is not None:
                ahead = ahead + (self.B @ u[:, t + j - 1, :, None])[..., 0]
            out[:, t, j] = torch.where(use, (self.C @ ahead[..., None])[..., 0], fallback_k[:, t, j])

    def update(self, y_t: Tensor, yhat_t: Tensor, u_t: Tensor | None) -> None:
        """m_{t+1} = A m_t + K (y_t - yhat_t) (+ B u_t)."""
        self.state = (self.A @ self.state[..., None] + self.K @ (y_t - yhat_t)[..., None])[..., 0]
        if self.B is not None:
            self.state = self.state + (self.B @ u_t[..., None])[..., 0]


def refuse_gaps(traj: Trajectories) -> Tensor:
    """traj.y in float64; MopError for missing outputs: the block Hankel matrices of N4SID need every output,
    and this implementation does not identify from data with gaps."""
    if traj.observed is not None:
        raise MopError(
            f"n4sid-kf needs every output, and these trajectories have {traj.num_missing} missing (NaN / "
            "empty cells); use rls, rls-best or last, or fill the gaps"
        )
    return traj.y.double()


@PREDICTORS.register("n4sid-kf", preset_options={"small": {"every": 10}, "smoke": {"every": 10}})
class N4SIDKalmanPredictor:
    """Subspace identification from the prefix + steady-state Kalman predictor ("n4sid-kf").

    order: identified state dimension n_hat; num_block_rows: Hankel block rows i (default ceil(n/m) + 1,
    at least 2); min_prefix: first t that may use an identified model (before it RLS-AR(2)); every:
    re-identify every `every` steps (1: at each t, the most accurate; larger is faster); min_columns,
    select: see n4sid_kalman_predict.
    """

    name = "n4sid-kf"

    def __init__(
        self,
        order: int = 4,
        num_block_rows: int | None = None,
        min_prefix: int = 20,
        every: int = 1,
        name: str = "n4sid-kf",
        min_columns: int | None = None,
        select: bool = True,
    ) -> None:
        if order < 1 or every < 1 or min_prefix < 1:
            raise MopError(
                f"n4sid-kf: order, every, min_prefix must be >= 1, got {order}, {every}, {min_prefix}"
            )
        self.order, self.num_block_rows, self.min_prefix, self.every, self.name = (
            order,
            num_block_rows,
            min_prefix,
            every,
            name,
        )
        self.min_columns, self.select = min_columns, select

    def _run(self, traj: Trajectories, steps: int, origin: int | None = None) -> Tensor:
        """n4sid_kalman_run on traj (the inputs where it has them); keeps its mask as self.model_used and
        says where the fallback made most predictions (warn_fallback)."""
        u = None if traj.u is None else traj.u.double()
        args = (self.order, self.num_block_rows, self.min_prefix, self.every, self.min_columns, self.select)
        out, self.model_used, start = n4sid_kalman_run(refuse_gaps(traj), steps, *args, u=u, origin=origin)
        warn_fallback(self.name, self.model_used, start, origin, "RLS-AR(2)" if u is None else "ARX(2, 2)")
        return out.to(traj.y.dtype)

    def predict(self, traj: Trajectories) -> Tensor:
        """(B, T+1, m); uses the inputs where traj has them (the model with inputs)."""
        return self._run(traj, 1)[:, :, 0]

    def simulate(self, traj: Trajectories, context: int) -> Tensor:
        """(B, T+1-c, m): forecast[:, c] alone (n4sid_kalman_forecast with origin c)."""
        return self._run(traj, traj.horizon + 1 - context, origin=context)[:, context]

    def forecast(self, traj: Trajectories, steps: int) -> Tensor:
        """(B, T+1, K, m): the identified model propagated with no measurement (n4sid_kalman_forecast)."""
        return self._run(traj, steps)


def warn_fallback(name: str, used: Tensor, start: int, origin: int | None, fallback: str) -> None:
    """A MopWarning when the fallback made at least half of the predictions that could come from an identified
    model (t >= t_0; with an origin, the simulations from it): the numbers are then mostly the fallback's
    (n4sid-kf once printed exactly arx's numbers, and nothing said so). used (B, T) from n4sid_kalman_run."""
    steps = used[:, start:] if origin is None else used[:, origin : origin + 1]
    share = 1 - steps.double().mean().item() if steps.numel() else 1.0
    what = "simulations" if origin is not None else f"predictions from t_0 = {start} on"
    if share >= 0.5:
        warnings.warn(
            MopWarning(
                f"{name}: its {fallback} fallback made {share:.0%} of the {what} (before t_0 there is too "
                "little data to identify; after it the fallback stands in where the identified model is "
                f"unstable or has not beaten it): these numbers are mostly {fallback}'s; the predictor's "
                "model_used holds the per-step mask"
            ),
            stacklevel=3,
        )
