"""The one shape every fitted identifier (ARX, N4SID) takes, and the predictor that runs it, fixed once fit.

A fitted model is linear in innovation form, in numpy float64:

    x_{t+1} = A x_t + B u_t + b + K (y_t - yhat_t),     yhat_t = C x_t + d,

x_t (n,) the state before y_t is read, so yhat_t predicts y_t from y_<t and u_<t (the mop convention,
mop.predictors); u_t acts between y_t and y_{t+1} (no direct term). b, d carry the offsets (ARX's intercept,
the estimation means N4SID removes). x0 is the state before a record starts (ARX: its lags at the estimation
means, for yhat_0; its lags at y_0, u_0 from t = 1 on; N4SID: 0, the mean).
- predict: the recursion above over the record from x_0 = x0 (ARX: x_t holds the measured lags, so K
  writes y_t into the state; N4SID: the steady-state Kalman predictor).
- forecast[t, j]: the state after y_<t propagated j steps with the deterministic model (K dropped) and the
  known inputs u_t..u_{t+j-1}.
- simulate(traj, C): y_C..y_T from the deterministic model, its state estimated from the context y_<C (see
  FittedPredictor.context_state); C = 0 simulates the whole record, its initial state fitted to the first
  outputs (the benchmark protocol: the state is not measured).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from torch import Tensor

from mop.errors import MopError, MopWarning
from mop.predictors import nan_beyond_horizon
from mop.registry import Registry
from mop.systems.base import Trajectories

# name -> the identifier's class: candidates, size, feasible, fit_grid (mop.identify.arx, mop.identify.n4sid)
IDENTIFIERS: Registry = Registry("fitted identifier")

# the identifiers' arrays: [(y (T_i, m), u (T_i, k))] of complete records, u (T_i, 0) without inputs
# (mop.identify.select.complete_record makes them from records)
Arrays = list[tuple[np.ndarray, np.ndarray]]

RCOND = 1e-8  # least-squares state estimates ignore directions the outputs see this weakly (unobservable)


@dataclass(frozen=True)
class LinearModel:
    """x_{t+1} = A x_t + B u_t + b + K (y_t - C x_t - d), yhat_t = C x_t + d; x0 the state before the record.
    Shapes: A (n, n), B (n, k), C (m, n), K (n, m), b (n,), d (m,), x0 (n,)."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    K: np.ndarray
    b: np.ndarray
    d: np.ndarray
    x0: np.ndarray

    @property
    def state_dim(self) -> int:
        return self.A.shape[0]

    def predictor_states(self, y: np.ndarray, u: np.ndarray, first: np.ndarray | None = None) -> np.ndarray:
        """X (B, T+1, n): X[:, t] the state after reading y_<t, u_<t; y (B, T+1, m), u (B, T+1, k). X[:, 0] =
        x0; y_0 is read into `first` (B, n) where given (ARX: its lags at the record's first values)."""
        F = self.A - self.K @ self.C  # (n, n)
        x = np.broadcast_to(self.x0 if first is None else first, (y.shape[0], self.state_dim)).copy()
        X = np.empty((*y.shape[:2], self.state_dim))
        for t in range(y.shape[1]):
            X[:, t] = x
            x = x @ F.T + y[:, t] @ self.K.T + u[:, t] @ self.B.T + (self.b - self.K @ self.d)
        X[:, 0] = self.x0
        return X

    def rollout(self, x: np.ndarray, u: np.ndarray, steps: int) -> np.ndarray:
        """(B, steps, m): yhat_j = C x_j + d from x_0 = x (B, n), x_{j+1} = A x_j + B u_j + b, with the
        inputs u (B, >= steps - 1, k)."""
        out = np.empty((x.shape[0], steps, self.C.shape[0]))
        with np.errstate(over="ignore", invalid="ignore"):  # an unstable model diverges: inf / NaN, scored so
            for j in range(steps):
                out[:, j] = x @ self.C.T + self.d
                if j + 1 < steps:
                    x = x @ self.A.T + u[:, j] @ self.B.T + self.b
        return out

    def fit_state(self, y: np.ndarray, u: np.ndarray, prior: np.ndarray) -> np.ndarray:
        """(B, n): the state x_s at the first of the outputs y (B, L, m) that best explains them by least
        squares under the deterministic model with the inputs u (B, L, k): x_s = prior + z, z the minimum-norm
        solution of y_{s+l} - rollout(prior)_l = C A^l z (directions the L outputs do not see stay at
        prior)."""
        L, n = y.shape[1], self.state_dim
        free = self.rollout(np.broadcast_to(prior, (y.shape[0], n)), u, L)  # (B, L, m)
        rows, AL = [], np.eye(n)
        for _ in range(L):
            rows.append(self.C @ AL)
            AL = self.A @ AL
        O = np.concatenate(rows)  # (L m, n): the observability matrix over the window
        resid = (y - free).reshape(y.shape[0], -1)  # (B, L m)
        if not np.isfinite(O).all() or not np.isfinite(resid).all():
            return np.broadcast_to(prior, (y.shape[0], n)).copy()
        z = np.linalg.lstsq(O, resid.T, rcond=RCOND)[0]  # (n, B)
        return prior + z.T

    def to_json(self) -> dict[str, Any]:
        return {k: getattr(self, k).tolist() for k in ("A", "B", "C", "K", "b", "d", "x0")}


def arrays_of(
    traj: Trajectories, m: int, k: int, who: str, read: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(y (B, T+1, m), u (B, T+1, k)) float64 numpy of traj; MopError if the dimensions differ from the fit's
    or an output it reads is missing (a fixed linear model reads every output): all of them, or only the
    first `read` (a simulation reads its context; what it simulates may have gaps, left out of its score)."""
    y = traj.y.detach().cpu().double().numpy()
    u = np.zeros((*y.shape[:2], 0)) if traj.u is None else traj.u.detach().cpu().double().numpy()
    if y.shape[-1] != m or u.shape[-1] != k:
        raise MopError(
            f"{who} was fitted on {m} output(s) and {k} input(s); these data have {y.shape[-1]} and "
            f"{u.shape[-1]}: give data with the estimation record's columns"
        )
    seen = y if read is None else y[:, :read]
    if np.isnan(seen).any():
        where = "" if read is None else f" among the {read} it reads before simulating"
        raise MopError(
            f"{who} needs every output it reads, and these data have {int(np.isnan(seen).sum())} missing"
            f"{where}; fill the gaps"
        )
    return y, u


# warn when an input channel's RMS z-score against the estimation record's inputs exceeds this (the learned
# models' mop.models.normalization.OOD_RMS, which this layer sits below)
OOD_RMS = 5.0


@dataclass
class FittedPredictor:
    """A fitted identifier as a mop Predictor: predict / forecast / simulate with the model fixed.

    kind: "arx" or "n4sid"; orders: e.g. {"p": 2, "q": 2} or {"n": 3}; info: what the fit recorded (the
    estimation file, the selection criterion and the held-out scores of the order grid)."""

    kind: str
    orders: dict[str, int]
    model: LinearModel
    output_dim: int
    input_dim: int
    info: dict[str, Any] = field(default_factory=dict)
    lag_state: bool = False
    name: str = ""

    def __post_init__(self) -> None:
        self.name = self.name or f"fitted-{self.kind}"

    def _arrays(self, traj: Trajectories, read: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        y, u = arrays_of(traj, self.output_dim, self.input_dim, self.name, read)
        self.check_inputs(u)
        return y, u

    def check_inputs(self, u: np.ndarray) -> None:
        """Warn (once) when the inputs u (B, T+1, k) lie far outside the estimation record's (its
        info["input_range"]: per-channel means and stds), as a learned model warns (OOD_RMS)."""
        stats = self.info.get("input_range")
        if stats is None or getattr(self, "_warned", False) or u.size == 0:
            return
        mean, std = np.asarray(stats[0]), np.asarray(stats[1])
        rms = np.sqrt((((u - mean) / std) ** 2).mean(axis=(0, 1)))  # (k,)
        worst = int(rms.argmax())
        if rms[worst] > OOD_RMS:
            self._warned = True
            where = self.info.get("estimation", "its estimation record")
            warnings.warn(
                f"the inputs lie far outside what {self.name} was fitted on ({where}): u{worst} is "
                f"{rms[worst]:.3g} estimation standard deviations from the estimation mean (RMS; the "
                "estimation record: 1); its simulation may be poor",
                MopWarning,
                stacklevel=4,
            )

    def states(self, y: np.ndarray, u: np.ndarray) -> np.ndarray:
        """(B, T+1, n): the predictor states over the record. lag_state (ARX): the lags before the record's
        start read as its first values y_0, u_0 (at rest there), not the estimation means x0, from t = 1
        on: a mismatch between measured and assumed lags is amplified by a high order's large coefficients
        (a cascaded-tanks record: one-step errors up to 5800 over t < r, against 0.1 after)."""
        if not self.lag_state:
            return self.model.predictor_states(y, u)
        p, q = self.orders["p"], self.orders["q"]
        rest = np.concatenate([np.tile(y[:, 0], p), np.tile(u[:, 0], q)], axis=-1)  # (B, n)
        return self.model.predictor_states(y, u, first=rest)

    def predict(self, traj: Trajectories) -> Tensor:
        """(B, T+1, m): yhat_t = C x_t + d, x_t the predictor state after y_<t, u_<t."""
        y, u = self._arrays(traj)
        X = self.states(y, u)
        return torch.from_numpy(X @ self.model.C.T + self.model.d).to(traj.y.dtype)

    def forecast(self, traj: Trajectories, steps: int) -> Tensor:
        """(B, T+1, K, m): forecast[:, t, j], the deterministic model run j steps from the state after
        y_<t."""
        y, u = self._arrays(traj)
        M = self.model
        X = self.states(y, u)  # (B, T+1, n)
        T1 = y.shape[1]
        u_ahead = np.concatenate([u, np.repeat(u[:, -1:], steps, axis=1)], axis=1)  # inputs past T: unused
        out = np.empty((*y.shape[:2], steps, y.shape[-1]))
        with np.errstate(over="ignore", invalid="ignore"):
            for j in range(steps):
                out[:, :, j] = X @ M.C.T + M.d
                X = X @ M.A.T + u_ahead[:, j : j + T1] @ M.B.T + M.b
        return nan_beyond_horizon(torch.from_numpy(out)).to(traj.y.dtype)

    def context_state(self, y: np.ndarray, u: np.ndarray, context: int) -> tuple[np.ndarray, int]:
        """(x_s (B, n), s): a state of the deterministic model at s <= context estimated from y_<context.

        lag_state (ARX, context >= 1): the state is the measured lags, x_context read from the context (lags
        before the record's start at its first values). Otherwise the last L = min(context, W) context
        outputs fit x_{context-L} by least squares (fit_state, around x0), W = max(10, 2 n); context 0: the
        first min(T+1, W) outputs fit x_0 (the only outputs there are)."""
        if self.lag_state and context >= 1:
            X = self.states(y[:, : context + 1], u[:, : context + 1])  # X[:, C] reads y_<C
            return X[:, context], context
        n, T1 = self.model.state_dim, y.shape[1]
        window = max(10, 2 * n)
        s = 0 if context == 0 else context - min(context, window)
        L = min(T1, window) if context == 0 else context - s
        return self.model.fit_state(y[:, s : s + L], u[:, s : s + L], self.model.x0), s

    def simulate(self, traj: Trajectories, context: int) -> Tensor:
        """(B, T+1-c, m): out[:, j] predicts y_{c+j} from y_<c and the inputs (c = context >= 0); outputs
        after the context may be missing (NaN): they are not read."""
        y, u = self._arrays(traj, read=max(context, 1))
        T1 = y.shape[1]
        if not 0 <= context < T1:
            raise MopError(f"simulation context must be in [0, T = {T1 - 1}], got {context}")
        x, s = self.context_state(y, u, context)
        sim = self.model.rollout(x, u[:, s:], T1 - s)  # (B, T+1-s, m): y_s..y_T
        return torch.from_numpy(sim[:, context - s :]).to(traj.y.dtype)

    def to_json(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "orders": self.orders,
            "output_dim": self.output_dim,
            "input_dim": self.input_dim,
            "model": self.model.to_json(),
            **self.info,
        }
