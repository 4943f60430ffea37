"""mop: meta-learned output prediction of dynamical systems.

Importing mop fills the registries with the built-in entries: the families (mop.systems), the classical
predictors (mop.filters) and the learned ones (mop.runs, one per model architecture). Experiments register
with mop.experiments, which `mop reproduce` imports.
"""

import mop.filters  # noqa: F401  (the classical predictors; imports mop.systems, the families)
from mop.runs import load_predictor as _load_predictor

__version__ = "0.1.0"


def load(run_dir, device="cpu"):
    """Load a trained predictor from a run directory (see mop.runs)."""
    return _load_predictor(run_dir, device=device)
