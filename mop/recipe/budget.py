"""A training budget in minutes, turned into a step count that depends only on the budget and the record.

`mop train --data REC --budget MINUTES` plans the records recipe's steps as

    steps = max(MIN_STEPS, min(budget_steps, data_steps))
    budget_steps = budget * 60 / step_seconds                     (what the budget buys on the reference CPU)
    step_seconds = NOMINAL_STEP_SECONDS * max(1, horizon / NOMINAL_HORIZON)
    data_steps = ceil(MAX_EPOCHS * windows / batch_size)          (no more passes over the record than this)

so the same record, budget and seed train the same steps (and weights) on every machine: the plan is a pure
function (plan_steps), and the wall time it takes is printed from the step time measured on this machine
(mop.train.estimate); on a loaded or slower machine it takes longer than the budget, and
`mop train --max-minutes` is the wall-clock limit.
Records of up to about 1000 samples keep the MIN_STEPS the recipe was tuned with.
NOMINAL_STEP_SECONDS is one step of the recipe's 1 x 32 model at batch 64 x 50 on a 2-core CPU (19-20 ms,
measured with `mop train --data`'s trial steps); windows longer than NOMINAL_HORIZON (a long ARX feature's)
cost proportionally more. MAX_EPOCHS keeps a short record where the recipe was tuned:
1000 steps of batch 64 over the 970 windows of a 1024-sample record are 66 passes.
Where the record, not the budget, limits the steps, the budget's rest buys the records recipe's deep LRU a
wider body (BudgetPlan.width: the widest of WIDTH_COST, a step's measured cost at each width, that the
steps at that cost fit in the budget).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

from mop.errors import MopError

DEFAULT_BUDGET_MINUTES = 5.0
NOMINAL_STEP_SECONDS = 0.02
NOMINAL_HORIZON = 50  # the windows' length NOMINAL_STEP_SECONDS was measured on
MAX_EPOCHS = 70
MIN_STEPS = 1000  # the recipe's steps on short records, as tuned (a record of up to ~1000 samples)
# What a step of the records recipe's deep LRU (2 layers, batch 16 x 200) costs at each width, relative to
# its width of 32: 26.6 / 55 ms a step on the 2-core CPU (the cascaded tanks' runs, one thread each, two
# jobs at once). Where the record, not the budget, limits the steps, the budget's rest buys width
# (BudgetPlan.width): measured on the cascaded tanks' test (seeds 0-2), 2 x 64 simulates at 0.3379 /
# 0.3287 / 0.3269 V (mean 0.331) against 0.3827 / 0.4307 / 0.3807 (0.398) for 2 x 32 at the same 3155
# steps. 2 x 128 (170 ms a step) is left out: 0.3925 on seed 0. On two synthetic short records (`--budget
# 30`, seeds 0-1) it is about even: the own-record tutorial's tank 0.0348 against 0.0331 for 2 x 32, a
# two-mass plant with a saturating actuator and friction (2000 samples, 7000 steps) 0.1184 against 0.1210.
WIDTH_COST = {32: 1.0, 64: 2.1}


@dataclasses.dataclass(frozen=True)
class BudgetPlan:
    """What a budget buys on one record: `steps` of `batch_size` windows, and why that many."""

    minutes: float
    windows: int
    batch_size: int
    steps: int
    limited_by: str  # "budget" or "record" (MAX_EPOCHS passes over its windows) or "minimum"
    step_seconds: float = NOMINAL_STEP_SECONDS  # a step's nominal cost on the reference CPU

    def width(self, base: int) -> int:
        """The network's width the budget buys: `base` where the budget limits the steps; where the record
        limits them (MAX_EPOCHS passes), the widest of WIDTH_COST whose steps at their cost relative to
        `base` the budget still buys (`base` itself unless it is a width of WIDTH_COST)."""
        if self.limited_by != "record" or base not in WIDTH_COST:
            return base
        seconds = self.minutes * 60
        affordable = [
            w
            for w, cost in WIDTH_COST.items()
            if w >= base and self.steps * self.step_seconds * cost / WIDTH_COST[base] <= seconds
        ]
        return max(affordable, default=base)

    def line(self, step_seconds: float | None = None, base_width: int | None = None) -> str:
        """One line for the user: the plan, and the time it takes at `step_seconds` (measured here); with
        `base_width`, the width the budget's rest buys where it is wider (BudgetPlan.width)."""
        passes = self.steps * self.batch_size / max(self.windows, 1)
        why = {
            "budget": f"the steps {self.minutes:g} min buy on a reference 2-core CPU at "
            f"{self.step_seconds * 1e3:.0f} ms a step, the same on every machine",
            "record": f"{MAX_EPOCHS} passes over the record's {self.windows} windows, within the budget",
            "minimum": f"the minimum of {MIN_STEPS} steps",
        }[self.limited_by]
        took = f"; about {self.steps * step_seconds / 60:.1f} min on this machine" if step_seconds else ""
        wide = self.width(base_width) if base_width else None
        wider = f"; the budget's rest widens the network to {wide}" if wide != base_width else ""
        return (
            f"budget: {self.minutes:g} min -> {self.steps} steps of batch {self.batch_size} "
            f"({passes:.1f} passes over the training windows; {why}){took}{wider}"
        )


def check_budget(minutes: float) -> float:
    """`minutes` as a float; MopError unless it is a positive finite number."""
    return check_minutes(minutes, "--budget")


def check_minutes(minutes: float, option: str) -> float:
    """`minutes` as a float; one-line MopError naming `option` unless it is a positive finite number."""
    try:
        value = float(minutes)
    except (TypeError, ValueError):
        raise MopError(f"{option} must be a number of minutes, got {minutes!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise MopError(f"{option} must be a positive number of minutes, got {minutes!r}")
    return value


def plan_steps(minutes: float, windows: int, batch_size: int, horizon: int = NOMINAL_HORIZON) -> BudgetPlan:
    """The steps `minutes` buy on a record of `windows` training windows of `horizon` steps (see the module
    docstring)."""
    minutes = check_budget(minutes)
    step_seconds = nominal_step_seconds(horizon)
    by_budget = steps_bought(minutes, horizon)
    by_record = math.ceil(MAX_EPOCHS * windows / batch_size)
    steps, why = (by_budget, "budget") if by_budget <= by_record else (by_record, "record")
    if steps < MIN_STEPS:
        steps, why = MIN_STEPS, "minimum"
    return BudgetPlan(minutes, windows, batch_size, steps, why, step_seconds)


def nominal_step_seconds(horizon: int) -> float:
    """One step's nominal cost (s) on the reference CPU on windows of `horizon` steps (module docstring)."""
    return NOMINAL_STEP_SECONDS * max(1.0, horizon / NOMINAL_HORIZON)


def steps_bought(minutes: float, horizon: int = NOMINAL_HORIZON) -> int:
    """The steps `minutes` buy on windows of `horizon` steps, whatever the record: a plan trains fewer where
    the record limits it (MAX_EPOCHS passes) and MIN_STEPS where that is more."""
    return int(check_budget(minutes) * 60 / nominal_step_seconds(horizon))


def budget_line(steps: int, minutes: float, horizon: int) -> str:
    """What a run of `steps` steps on windows of `horizon` steps made of a budget of `minutes`: 'what the
    budget buys' where it trained that, else that the budget did not set the steps (the record's MAX_EPOCHS
    passes, the MIN_STEPS floor, or a schedule of the run's own), so a larger budget trains the same steps
    (where the record limits them, a wider network: BudgetPlan.width)."""
    bought = steps_bought(minutes, horizon)
    if steps == bought:
        return f"{steps} steps, what the {minutes:g}-min budget buys"
    than, why = (
        ("fewer", f"the record's limit of {MAX_EPOCHS} passes over its training windows")
        if steps < bought
        else ("more", f"the recipe's minimum of {MIN_STEPS}")
    )
    return (
        f"{steps} steps, {than} than the {bought} the {minutes:g}-min budget buys ({why}, or train.steps or "
        "a fine-tune's own schedule): a larger --budget trains the same steps"
    )


def plan_windows(
    minutes: float, lengths: Sequence[int], batch_size: int, horizon: int = NOMINAL_HORIZON
) -> BudgetPlan:
    """plan_steps on training parts of these `lengths`: each part of L steps holds L - horizon windows of
    horizon + 1 steps (mop.train.records.window_count, counted from the lengths alone)."""
    return plan_steps(minutes, sum(max(0, n - horizon) for n in lengths), batch_size, horizon)
