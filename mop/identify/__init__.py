"""Fitted (batch, offline) identifiers, the system-identification field's baselines: fitted once on an
estimation record, then fixed. "arx" (least squares) and "n4sid" (subspace), their orders chosen on held-out
data (select.fit), saved as a directory with fitted.json (store). Each is a mop Predictor (linear)."""

from mop.identify import arx, n4sid  # noqa: F401 (each module registers its identifier)
from mop.identify.linear import IDENTIFIERS, FittedPredictor, LinearModel
from mop.identify.select import fit
from mop.identify.store import is_fitted, load, save

__all__ = ["IDENTIFIERS", "FittedPredictor", "LinearModel", "fit", "is_fitted", "load", "save"]
