"""What the records recipe decides for one record (mop.recipe.records.plan_records): the feature, its orders,
the model, the windows and the steps, in one place.

Where no model.arch is named, a records run is RECORDS_BODY: the deep LRU trained on its free-run
simulation error, reading no feature (p = 0 in its plan: RECORDED_MODEL's sizes and the steps, then the
body's). With model.arch=gpt it is RECORDED_MODEL (a 1 x 32 transformer) reading the one-step prediction of
an ARX(p, q) feature with an intercept, started from its least-squares fit on the record's training part,
and predicting its residual: `cubes` of its output lags also cubed (a cubic NARX), or, for a long ARX
(`fixed`), held at that fit; trained `steps` steps (the budget's plan) on windows of `horizon` steps. Any
other architecture that reads no input features (model.arch=gru) gets RECORDED_MODEL and the steps alone.
"""

from __future__ import annotations

import dataclasses

from mop.config import FEATURE_RUN
from mop.models.lru import NAME as DEEP_LRU
from mop.recipe.budget import BudgetPlan

# The records recipe (docs/results/families.md: measured on examples/tank_records.py, one record of 1024
# samples): a small network reading the fitted ARX's prediction and predicting its residual, so it starts as
# that ARX; the 2 x 64 small-preset model trained 2500 steps overfits one record (one-step RMSE 2.5x ARX's)
RECORDED_MODEL = {"model.num_layers": 1, "model.width": 32, "model.num_heads": 2}

# The records recipe's network where no model.arch is named: the deep LRU (mop.models.lru), 2 layers of 32,
# trained on its free-run simulation error (train.simulate_after, mop.train.data: each window's outputs from a
# random step s >= SIMULATE_AFTER read as missing and scored), on windows of up to RECORDS_HORIZON steps, 16
# a step. Measured on the real benchmarks (docs/results/benchmarks.md, the 2-core CPU, 5 minutes): below the
# transformer reading the ARX feature on the cascaded tanks, the F-16 and the F-16 with three outputs, and
# kept by the held-out check on all four (the transformer's correction at gain 0 on three). Its width is
# the budget's (mop.recipe.records.with_recorded_features, BudgetPlan.width): 32 where the budget limits the
# steps, wider where a short record's passes leave the budget room.
RECORDS_BODY = {
    "model.arch": DEEP_LRU,
    "model.num_layers": 2,
    "model.width": 32,
    "model.observation_mask": True,
    "model.forecast_mode": "gap",
    "train.simulate_after": 5,
    "train.batch_size": 16,
    "data.feature_input": FEATURE_RUN,
}
RECORDS_HORIZON = 200  # the body's training windows (and context), at most; shorter on a shorter record


@dataclasses.dataclass(frozen=True)
class RecordsPlan:
    """The records recipe's choice for one record (see the module docstring).

    p, q: the feature's output and input lags; cubes: how many of the output lags are also cubed (0: linear);
    fixed: the feature stays at its least-squares fit (a long ARX, mop.identify.long_arx); horizon: the
    training windows' length, `longer` where the feature's orders asked for longer windows than the config's;
    context: the model's context (at least horizon); budget: the steps the budget buys (budget.steps)."""

    p: int
    q: int
    cubes: int
    fixed: bool
    horizon: int
    longer: bool
    context: int
    budget: BudgetPlan

    @property
    def steps(self) -> int:
        return self.budget.steps

    def settings(self) -> dict[str, object]:
        """The plan as the RunConfig's dotted keys (mop.config.apply_settings), as a records run trains it."""
        longer = {"train.horizon": self.horizon, "model.context": self.context} if self.longer else {}
        steps = {**RECORDED_MODEL, **longer, "train.steps": self.steps}
        if self.p == 0:  # no feature: an architecture that reads none
            return steps
        return {
            **steps,
            **({"model.rls_fixed": True} if self.fixed else {}),
            "model.rls_order": self.p,
            "model.arx_order": self.q,
            "model.rls_cubes": self.cubes,
            "model.rls_offset": True,
            "model.rls_prior": "fit",
        }
