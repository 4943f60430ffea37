"""The records recipe's least-squares feature as a model of its own: a cubic NARX fitted once, then fixed.

    y_{t+1} = theta' [y_t..y_{t-p+1}, y_t^3..y_{t-c+1}^3, u_t..u_{t-q+1}, 1]

in the record's normalised units (each channel minus its estimation mean, over its std; the cubes are of the
normalised outputs), as mop.identify.cubic fits and scores it: c = 0 is an ARX(p, q) with an intercept. The
records recipe (mop.recipe.records) chooses (p, q, c) on a record's training part; the held-out check
(mop.recipe.selection) scores this model beside the network and the fitted ARX and N4SID, and a run that
keeps it holds it as fitted.json (kind "cubic-narx"), which `mop predict` and mop.load read as they read a
`mop fit` folder. Lags before a record's start are its first values (at rest there), as the fitted ARX's.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from mop.errors import MopError
from mop.filters.arx import least_squares_coefficients
from mop.identify.linear import arrays_of
from mop.identify.select import complete_record, input_range
from mop.predictors import nan_beyond_horizon
from mop.record import RecordsLike, fingerprint, to_records
from mop.systems.base import Trajectories

KIND = "cubic-narx"


@dataclass
class FittedNARX:
    """A fitted cubic NARX as a mop Predictor: predict / forecast / simulate with theta fixed.

    orders: {"p", "q", "c"}; theta (p m + c m + q k + 1, m), the rows in mop.identify.cubic.regressor_rows'
    order; y_mean, y_std (m,), u_mean, u_std (k,): the normalisation it was fitted in."""

    orders: dict[str, int]
    theta: np.ndarray
    y_mean: np.ndarray
    y_std: np.ndarray
    u_mean: np.ndarray
    u_std: np.ndarray
    info: dict[str, Any] = field(default_factory=dict)
    kind: str = KIND
    name: str = ""

    def __post_init__(self) -> None:
        p, q, c = self.orders["p"], self.orders["q"], self.orders["c"]
        rows = (p + c) * self.output_dim + q * self.input_dim + 1
        if self.theta.shape != (rows, self.output_dim) or not 0 <= c <= p:
            raise ValueError(f"theta {self.theta.shape} does not fit orders {self.orders}")
        self.name = self.name or f"fitted-{KIND}({p}, {q}, c={c})"

    @property
    def output_dim(self) -> int:
        return len(self.y_mean)

    @property
    def input_dim(self) -> int:
        return len(self.u_mean)

    @property
    def lags(self) -> int:
        return max(self.orders["p"], self.orders["q"], 1)

    def _padded(self, traj: Trajectories, read: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(y, u) normalised (B, r + T+1, .), each preceded by r = max(p, q) copies of its first value."""
        y, u = arrays_of(traj, self.output_dim, self.input_dim, self.name, read)
        y, u = (y - self.y_mean) / self.y_std, (u - self.u_mean) / self.u_std
        r = self.lags
        pad = lambda a: np.concatenate([np.repeat(a[:, :1], r, axis=1), a], axis=1)  # noqa: E731
        return pad(y), pad(u)

    def _next(self, ylags: np.ndarray, ulags: np.ndarray) -> np.ndarray:
        """(..., m): the normalised prediction from ylags (..., p, m) and ulags (..., q, k), newest first."""
        q, c = self.orders["q"], self.orders["c"]
        phi = [ylags.reshape(*ylags.shape[:-2], -1)]
        if c:
            phi.append(ylags[..., :c, :].reshape(*ylags.shape[:-2], -1) ** 3)
        if q:
            phi.append(ulags.reshape(*ulags.shape[:-2], -1))
        phi.append(np.ones((*ylags.shape[:-2], 1)))
        with np.errstate(over="ignore", invalid="ignore"):  # a diverging run overflows: scored as diverged
            return np.concatenate(phi, axis=-1) @ self.theta

    def _out(self, z: np.ndarray, like: Tensor) -> Tensor:
        return torch.from_numpy(z * self.y_std + self.y_mean).to(like.dtype)

    @staticmethod
    def _window(a: np.ndarray, end: np.ndarray | int, n: int) -> np.ndarray:
        """a[:, end-1], ..., a[:, end-n] stacked newest first along a new axis -2 (end: an index or an array
        of them)."""
        if n == 0:
            return np.zeros((*a[:, end].shape[:-1], 0, a.shape[-1]))
        return np.stack([a[:, end - 1 - j] for j in range(n)], axis=-2)

    def predict(self, traj: Trajectories) -> Tensor:
        """(B, T+1, m): yhat_t from the measured y_<t and u_<t."""
        y, u = self._padded(traj)
        r, T1 = self.lags, y.shape[1] - self.lags
        ends = np.arange(r, r + T1)  # padded index of y_t: the lags end just before it
        ylags, ulags = self._window(y, ends, self.orders["p"]), self._window(u, ends, self.orders["q"])
        return self._out(self._next(ylags, ulags), traj.y)

    def _roll(self, y: np.ndarray, u: np.ndarray, start: int, steps: int) -> np.ndarray:
        """(B, steps, m) normalised: y_start.. simulated from the padded y (B, r + T+1, m) before padded index
        r + start and the inputs; y is overwritten from there on."""
        r, p, q = self.lags, self.orders["p"], self.orders["q"]
        for s in range(r + start, r + start + steps):
            y[:, s] = self._next(self._window(y, s, p), self._window(u, s, q))
        return y[:, r + start : r + start + steps]

    def simulate(self, traj: Trajectories, context: int) -> Tensor:
        """(B, T+1-c, m): out[:, j] predicts y_{c+j} from y_<c and the inputs (c = context >= 1); outputs
        after the context may be missing (NaN): they are not read."""
        y, u = self._padded(traj, read=max(context, 1))
        T1 = y.shape[1] - self.lags
        if not 1 <= context < T1:
            raise MopError(f"simulation context must be in [1, T = {T1 - 1}], got {context}")
        return self._out(self._roll(y, u, context, T1 - context), traj.y)

    def forecast(self, traj: Trajectories, steps: int) -> Tensor:
        """(B, T+1, K, m): forecast[:, t, j] predicts y_{t+j} from y_<t and the inputs (NaN past T)."""
        y, u = self._padded(traj)
        B, r, T1 = y.shape[0], self.lags, y.shape[1] - self.lags
        u = np.concatenate([u, np.repeat(u[:, -1:], steps, axis=1)], axis=1)  # inputs past T: unused
        out = np.empty((B, T1, steps, self.output_dim))
        for t in range(T1):  # each origin rolled from its measured lags, all records at once
            buf = np.concatenate([y[:, : r + t], np.zeros((B, steps, y.shape[2]))], axis=1)
            out[:, t] = self._roll(buf, u[:, : r + t + steps], t, steps)
        return nan_beyond_horizon(self._out(out, traj.y))

    def to_json(self) -> dict[str, Any]:
        return {
            "kind": KIND,
            "orders": dict(self.orders),
            "output_dim": self.output_dim,
            "input_dim": self.input_dim,
            "model": {
                "theta": self.theta.tolist(),
                **{k: getattr(self, k).tolist() for k in ("y_mean", "y_std", "u_mean", "u_std")},
            },
            **self.info,
        }

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> FittedNARX:
        """The model to_json wrote (ValueError / KeyError where it does not fit together)."""
        model = {k: np.asarray(v, dtype=np.float64) for k, v in d["model"].items()}
        m, k = int(d["output_dim"]), int(d["input_dim"])
        if model["y_mean"].shape != (m,) or model["u_mean"].shape != (k,):
            raise ValueError("the normalisation does not fit output_dim / input_dim")
        info = {
            k: v
            for k, v in d.items()
            if k not in ("format", "kind", "orders", "output_dim", "input_dim", "model")
        }
        orders = {key: int(v) for key, v in d["orders"].items()}
        return cls(orders, model["theta"].reshape(-1, m), **_moments(model), info=info)


def _moments(model: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    return {k: model[k].reshape(-1) for k in ("y_mean", "y_std", "u_mean", "u_std")}


RIDGE = 1e-6  # per pair, as the transformer's feature prior (mop.train.records.RIDGE)


def fit_cubic_narx(
    data: RecordsLike,
    p: int,
    q: int,
    c: int,
    source: str = "record",
    moments: dict | None = None,
    ridge: float = RIDGE,
) -> FittedNARX:
    """The cubic NARX (p, q, c) fitted by least squares on every step of `data`, in the normalisation
    `moments` ({"y_mean", "y_std", "u_mean", "u_std"}: the record's own per-channel moments where None):
    mop.filters.arx.least_squares_coefficients, the coefficients a transformer's feature starts from
    (model.rls_prior=fit), with their ridge (RIDGE; 0: plain least squares; on Silverbox's training part
    the relative 1e-8 of mop.identify.cubic's choice simulated the tests 5% worse). MopError where the
    record has missing outputs or too few steps for the orders."""
    record = complete_record(to_records(data), source)
    m, k = record[0][0].shape[1], record[0][1].shape[1]
    if moments is None:
        y, u = np.concatenate([y for y, _ in record]), np.concatenate([u for _, u in record])
        std = lambda a: np.where(a.std(0) > 0, a.std(0), 1.0)  # noqa: E731
        moments = {"y_mean": y.mean(0), "y_std": std(y), "u_mean": u.mean(0), "u_std": std(u)}
    mo = {key: np.asarray(v, dtype=np.float64).reshape(-1) for key, v in moments.items()}
    steps = sum(len(y) - max(p, q) for y, _ in record)
    if steps < (p + c) * m + q * k + 1:
        raise MopError(f"{source}: {steps} steps are too few to fit a cubic NARX ({p}, {q}, c={c})")
    z = [
        np.concatenate([(y - mo["y_mean"]) / mo["y_std"], (u - mo["u_mean"]) / mo["u_std"]], 1)
        for y, u in record
    ]
    theta = least_squares_coefficients(z, m, p, q, True, c, ridge)
    info = {"estimation": Path(source).name, "select": "given", "fingerprint": fingerprint(record)}
    info["input_range"] = input_range(record)
    return FittedNARX({"p": p, "q": q, "c": c}, theta, **mo, info=info)
