"""mop: meta-learned output prediction of dynamical systems.

Importing mop fills the registries with the built-in entries: the families (mop.systems), the classical
predictors (mop.filters) and the learned ones (mop.runs, one per model architecture). Experiments register
with mop.experiments, which `mop reproduce` imports.
"""

import mop.filters  # noqa: F401  (the classical predictors; imports mop.systems, the families)
from mop.record import Record, read_records

__version__ = "0.1.0"


__all__ = ["Record", "load", "read_records"]


def load(run_dir, device="cpu", context=None):
    """A saved model as an estimator with the face of mop.estimators.ARX / Learned (fit, predict, forecast,
    simulate on a mop.Record, numpy out in the record's units): a trained run directory (mop train), a
    shipped one, `pretrained:NAME` (`mop pretrained` lists them), or a fitted model's directory (mop fit).
    context: records a shipped class model reads before each simulation, as `mop predict --context`.
    Given mop.systems.base.Trajectories its predict / forecast / simulate return the predictor's tensors.
    See mop.estimators.Loaded."""
    from mop.estimators import load as _load  # the estimators import the recipe: loaded on first use

    return _load(run_dir, device=device, context=context)
