"""sysidentpy's FROLS polynomial NARX with the library's defaults but one, as a peer under mop's protocol.

FROLS (forward-regression orthogonal least squares, Billings) picks the terms of a degree-2 polynomial in
y_{t-1..t-2} and u_{t-1..t-2} by the error reduction ratio and their number by AIC:
`sysidentpy.model_structure_selection.FROLS(estimator=LeastSquares())`, every other option as the library
ships it (model_type "NARMAX": the noise terms are dropped in a free run). On purpose, the parameters are
fitted by least squares over the whole record: 0.9.0's default estimator is recursive least squares with a
forgetting factor of 0.98, which weighs about the record's last 50 samples; with it the free runs were
1.372 V on the cascaded tanks (0.8081 with least squares) and 12.31 / 20.34 / 10.12 mV on Silverbox
(7.788 / 15.6 / 7.057), `mop benchmark NAME --predictors narx` on the 2-core CPU.

FROLS takes one record: several estimation records are joined end to end (the max_lag steps after each
join read the previous record's end). The free run starts from the last max_lag of the n measured outputs,
sysidentpy's own initial condition, so y_n.. are simulated from the inputs alone as the protocol asks.

An optional extra: `pip install --no-deps sysidentpy==0.9.0` (its metadata pins numpy <= 2.3.5; 0.9.0 runs
with mop's numpy, which its tests here check). One output only (FROLS is multi-input, single-output).
"""

from __future__ import annotations

import importlib

import numpy as np
from torch import Tensor

from mop.errors import MopError
from mop.peers.runs import free_runs
from mop.record import Record
from mop.systems.base import Trajectories

INSTALL = "pip install --no-deps sysidentpy==0.9.0"


def frols_class() -> type:
    """sysidentpy's FROLS class; a one-line MopError naming the install command where it is missing."""
    return _sysidentpy("model_structure_selection").FROLS


def least_squares() -> object:
    """sysidentpy's least-squares estimator (see the module docstring for why it, not the default)."""
    return _sysidentpy("parameter_estimation").LeastSquares()


def _sysidentpy(module: str):
    try:
        return importlib.import_module(f"sysidentpy.{module}")
    except ImportError:
        raise MopError(f"the narx peer is sysidentpy's FROLS, which is not installed: {INSTALL}") from None


class NarxPredictor:
    """A fitted FROLS NARX as a mop Predictor: simulate(traj, context) in the data's units (traj's y
    (B, T+1, 1), u (B, T+1, k))."""

    name = "narx"

    def __init__(self, model) -> None:
        self.model = model
        self.max_lag = int(model.max_lag)

    def simulate(self, traj: Trajectories, context: int) -> Tensor:
        """(B, T+1-c, 1): y_c..y_T from y_{c-L}..y_{c-1} (L = max_lag) and the inputs."""
        L = self.max_lag

        def run(y: np.ndarray, u: np.ndarray) -> np.ndarray:
            return self.model.predict(X=u, y=y[:L])[L:]  # sysidentpy returns the L given outputs first

        return free_runs(traj, context, L, self.name, "starts its free run", run)


def fit_narx(records: list[Record]) -> NarxPredictor:
    """FROLS(estimator=LeastSquares()), fitted on the records joined end to end (the module docstring)."""
    if any(r.u is None or r.y.shape[1] > 1 for r in records):
        raise MopError(
            "the narx peer (FROLS) fits one output from inputs: give single-output records with inputs"
        )
    y = np.concatenate([np.asarray(r.y, dtype=float) for r in records])  # (T, 1)
    u = np.concatenate([np.asarray(r.u, dtype=float) for r in records])  # (T, k)
    if not (np.isfinite(y).all() and np.isfinite(u).all()):
        raise MopError("the narx peer (FROLS) needs complete records: fill the missing samples first")
    model = frols_class()(estimator=least_squares())
    model.fit(X=u, y=y)
    return NarxPredictor(model)


def narx_line(predictor: NarxPredictor) -> str:
    """One line on what FROLS chose: its number of terms and lags."""
    terms = len(predictor.model.final_model)
    lag = predictor.max_lag
    return f"sysidentpy FROLS, least squares: a degree-2 polynomial NARX of {terms} terms, max lag {lag}"
