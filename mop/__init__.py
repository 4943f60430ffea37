"""mop: meta-learned output prediction of dynamical systems.

Importing mop fills the registries with the built-in entries: the families (mop.systems), the classical
predictors (mop.filters) and the learned ones (mop.runs, one per model architecture). Experiments register
with mop.experiments, which `mop reproduce` imports.
"""

import importlib

import mop.filters  # noqa: F401  (the classical predictors; imports mop.systems, the families)
import mop.runs  # noqa: F401  (the learned predictors, one per model architecture)
from mop.record import Record, read_records

__version__ = "0.1.0"


__all__ = ["Record", "load", "read_records"]


# Attributes loaded on first use (PEP 562), {name: module}: mop.load is mop.estimators.load, whose fine-tune
# and in-context paths import the trainer, so that `import mop.runs` alone stays free of it.
# tests/test_layers.py counts these as imports of the package.
LAZY = {"load": "mop.estimators"}


def __getattr__(name: str):
    if name in LAZY:
        return getattr(importlib.import_module(LAZY[name]), name)
    raise AttributeError(f"module 'mop' has no attribute {name!r}")
