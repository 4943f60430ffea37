"""mop: meta-learned output prediction of dynamical systems.

Importing mop fills the registries with the built-in entries: the families (mop.systems), the classical
predictors (mop.filters) and the learned ones (mop.runs, one per model architecture). Experiments register
with mop.experiments, which `mop reproduce` imports.
"""

import mop.filters  # noqa: F401  (the classical predictors; imports mop.systems, the families)
from mop.identify import is_fitted as _is_fitted
from mop.identify import load as _load_fitted
from mop.record import Record, read_records
from mop.runs import load_predictor as _load_predictor

__version__ = "0.1.0"


__all__ = ["Record", "load", "read_records"]


def load(run_dir, device="cpu"):
    """Load a predictor as `mop predict` does: a trained run directory (mop train), a shipped one,
    `pretrained:NAME` (see mop.runs; `mop pretrained` lists them), or a fitted model's directory (mop fit)."""
    if _is_fitted(run_dir):
        return _load_fitted(run_dir)
    return _load_predictor(run_dir, device=device)
