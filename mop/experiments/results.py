"""What the runner hands to analyses, measures and figures: one typed result per test condition.

    result.errors["kalman"]        (N, T+1) per-system errors ||yhat_t - y_t|| of predictor "kalman"
    result.summary["predictors"]   eval.json's curves and window means per predictor (mop.evaluate.summarize)
    result.extras["calibration"]   what the experiment's analyses returned, merged

Results of an experiment are a dict condition name -> ConditionResult, in the experiment's order.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from mop.experiments.spec import Condition
from mop.systems.base import Trajectories


@dataclasses.dataclass
class ConditionResult:
    """One test condition's outcome: trajectories, per-system errors e (N, T+1) per predictor, the eval.json
    summary and the analyses' extras."""

    condition: Condition
    traj: Trajectories
    errors: dict[str, np.ndarray]
    summary: dict[str, Any]
    extras: dict[str, Any] = dataclasses.field(default_factory=dict)


Results = dict[str, ConditionResult]
