"""The records recipe: what `mop train --data FILE` trains on one user's record when nothing else is named.

Before training (plan_records, layer 3 of mop.recipe.layers): the least-squares feature (feature_orders):
the ARX orders `mop fit arx` chooses on the record's training part, cubed output lags where a cubic NARX
simulates the held-out end of that part better (mop.identify.cubic), else a longer ARX where a long record
supports one (mop.identify.long_arx); the network: where no model.arch is named, the deep LRU trained on
its free-run simulation error (RECORDS_BODY, records_body: mop.recipe.plan), which reads no feature, so the
feature is left to the held-out check as a model of its own; with model.arch=gpt the transformer
RECORDED_MODEL reading the feature started from its least-squares fit (windows of at least twice its orders;
a long ARX fixed at its fit, model.rls_fixed, as the recursion would cost most of each step); and the steps
the budget buys on the record (mop.recipe.budget): a RecordsPlan (mop.recipe.plan), planned from the
record's training part handed over once (mop.train.records.TrainingPart: nothing here reads a file or asks
the record again). After training: the held-out choice between the network (and, for the transformer, its
correction at each gain) and the least-squares models (mop.recipe.selection). feature_line, body_line and
order_line say what was chosen and why.
"""

from __future__ import annotations

import numpy as np

from mop.config import (
    RunConfig,
    apply_settings,
    parse_overrides,
)
from mop.errors import MopError
from mop.identify.arx import ARX
from mop.identify.cubic import EXTRA_LAGS, choose_cubes
from mop.identify.long_arx import LONG_ORDERS, choose_long_orders
from mop.identify.narx_model import FittedNARX, fit_cubic_narx
from mop.identify.select import chosen_orders, feasible_order, fit, largest_order
from mop.models import reads_features
from mop.recipe.budget import DEFAULT_BUDGET_MINUTES, BudgetPlan, plan_windows
from mop.recipe.plan import RECORDED_MODEL, RECORDS_BODY, RECORDS_HORIZON, RecordsPlan
from mop.record import RecordsLike
from mop.train.auto import FEATURE_KEYS as AUTO_KEYS
from mop.train.records import RecordedData, TrainingPart, TrainingRecords

__all__ = ["RECORDED_MODEL", "RecordsPlan", "plan_records"]

# the identifier's keys (mop.train.auto's feature keys but the running scale): naming one turns the recipe off
FEATURE_KEYS = tuple(f"model.{key}" for key in AUTO_KEYS if key != "input_scale")
# the overrides the plan is made with (the steps a budget buys depend on the windows' length)
WINDOW_KEYS = ("train.horizon", "train.batch_size", "model.context")


def arx_orders(data: RecordsLike, source: str) -> tuple[int, int] | None:
    """(p, q): the ARX orders `mop fit arx` chooses on `data` (mop.identify.select.fit: free-run
    simulation of its last 20%); on data too short for orders up to 10, those of `--max-order P` with the
    largest P it allows; None where it allows none."""
    largest = feasible_order(ARX.kind, data, source=source)
    if largest == 0:
        return None
    orders = fit(ARX.kind, data, max_order=largest, source=source).orders
    return orders["p"], orders["q"]


def fitted_long_orders(
    part: TrainingPart, p: int, q: int, max_order: int = max(LONG_ORDERS)
) -> tuple[int, int]:
    """(p, q): the ARX orders of the records recipe's linear feature, `mop fit arx`'s (p, q) or a longer
    ARX(P, P), P <= max_order, where the record is long enough and it simulates the last 20% of the training
    part better (mop.identify.long_arx.choose_long_orders on the normalised training part)."""
    return (p, q) if part.normalised is None else choose_long_orders(part.normalised, p, q, max_order)[:2]


def record_orders(record: RecordedData) -> tuple[int, int] | None:
    """(p, q): arx_orders on the whole estimation record (record.given), its validation part included: the
    orders of `mop fit arx FILE`."""
    return arx_orders(list(record.given.records), record.path)


def budget_plan(
    part: TrainingPart, batch_size: int, horizon: int, minutes: float = DEFAULT_BUDGET_MINUTES
) -> BudgetPlan:
    """The steps `minutes` buy on the training part's windows of `horizon` steps, `batch_size` windows a
    step (mop.recipe.budget.plan_windows)."""
    return plan_windows(minutes, part.lengths, batch_size, horizon)


def feature_horizon(horizon: int, p: int, q: int) -> int:
    """The training windows' length for a feature of orders (p, q): at least 2 max(p, q), so that the
    feature regresses (rather than holding its start-up's last value) on at least half of every window."""
    return max(horizon, 2 * max(p, q))


def plan_records(
    part: TrainingPart,
    config: RunConfig,
    budget: float = DEFAULT_BUDGET_MINUTES,
    cubes: bool = True,
    feature: bool = True,
) -> RecordsPlan:
    """The records recipe's plan for a record's training part (`part`: RecordedData.training_part, the
    arrays the plan needs, made once; nothing is read from disk and nothing is asked of the record again),
    in one sequence: the ARX orders `mop fit arx` chooses on the training part (mop.identify.select), cubed
    output lags where a cubic NARX simulates the held-out end of the training part better
    (mop.identify.cubic.choose_cubes, on the part normalised as the network reads it), else the longer ARX
    orders a long record supports (mop.identify.long_arx.choose_long_orders) with windows of
    feature_horizon, the feature started from their least-squares fit, RECORDED_MODEL, and the steps the
    budget (minutes) buys on the record (mop.recipe.budget.plan_windows: longer records train longer).
    config gives the windows' length, the batch size and the model's context the plan starts from. A pure
    function of its arguments: the same part gives the same plan. feature=False (an architecture that reads
    no input features, e.g. model.arch=deep-lru): no feature (the training part must still fit an ARX, which
    the held-out check compares with), the config's windows, the steps the budget buys."""
    if not feature:
        arx_fits(part)
        horizon = config.train.horizon
        budget_plan = plan_windows(budget, part.lengths, config.train.batch_size, horizon)
        return RecordsPlan(0, 0, 0, False, horizon, False, config.model.context, budget_plan)
    p, q, c, fixed = feature_orders(part, cubes)
    horizon = feature_horizon(config.train.horizon, p, q)
    return RecordsPlan(
        p=p,
        q=q,
        cubes=c,
        fixed=fixed,
        horizon=horizon,
        longer=horizon > config.train.horizon,
        context=max(config.model.context, horizon),
        budget=plan_windows(budget, part.lengths, config.train.batch_size, horizon),
    )


def arx_fits(part: TrainingPart) -> int:
    """The largest ARX order the training part allows (mop.identify.select.largest_order); MopError where it
    allows none: the recipe's feature, and the held-out check's fitted ARX, need one."""
    largest = largest_order(ARX.kind, part.pairs)
    if largest == 0:
        raise MopError(
            f"{part.source}: its training part is too short to fit the records recipe's ARX feature (which "
            "its held-out check compares the network with); give a longer record, or name the model's "
            "feature (model.rls_order=0 for none)"
        )
    return largest


def feature_orders(part: TrainingPart, cubes: bool = True) -> tuple[int, int, int, bool]:
    """(p, q, c, fixed): the records recipe's least-squares feature on a record's training part: the ARX
    orders `mop fit arx` chooses there (mop.identify.select), c of the output lags cubed where a cubic NARX
    simulates the held-out end of the part better (mop.identify.cubic.choose_cubes; cubes=False: c = 0),
    else the longer ARX(P, P) a long record supports (mop.identify.long_arx; fixed True: held at its fit)."""
    return _orders_from(part, *_arx_orders(part), cubes)


def _arx_orders(part: TrainingPart) -> tuple[int, int]:
    """The ARX orders (p, q) `mop fit arx` chooses on the training part (its grid of fits and free runs)."""
    orders = chosen_orders(ARX.kind, part.pairs, max_order=arx_fits(part), source=part.source)
    return orders["p"], orders["q"]


def _orders_from(part: TrainingPart, p: int, q: int, cubes: bool) -> tuple[int, int, int, bool]:
    """feature_orders from the chosen ARX orders (p, q)."""
    c = 0
    if cubes and part.normalised is not None:  # (p, 0) keeps the ARX(p, q) `mop fit arx` chose
        p, c = choose_cubes(part.normalised, p, q)[:2]
    if c == 0 and part.normalised is not None:
        p, q = choose_long_orders(part.normalised, p, q, max(LONG_ORDERS))[:2]
    return p, q, c, max(p, q) in LONG_ORDERS and c == 0


def fitted_feature(record: RecordedData, cubes: bool = True) -> tuple[FittedNARX, bool]:
    """(the records recipe's least-squares feature fitted on the record's training part in its
    normalisation (feature_orders; cubes=False: without cubed lags; mop.identify.narx_model), whether it is
    more than the fitted ARX: cubed output lags or a long ARX)."""
    p, q, c, fixed = feature_orders(record.training_part, cubes)
    return _fitted(record, p, q, c), c > 0 or fixed


def fitted_features(record: RecordedData) -> tuple[FittedNARX, FittedNARX | None]:
    """(fitted_feature's feature, the same without cubed lags where it has some, else None), the ARX orders
    searched once for both (on Silverbox's training part the search takes about 40 s)."""
    part = record.training_part
    p, q = _arx_orders(part)
    chosen = _orders_from(part, p, q, True)
    linear = _orders_from(part, p, q, False) if chosen[2] > 0 else None
    return _fitted(record, *chosen[:3]), None if linear is None else _fitted(record, *linear[:3])


def _fitted(record: RecordedData, p: int, q: int, c: int) -> FittedNARX:
    """The NARX of orders (p, q, c) fitted on the record's training parts in its normalisation."""
    m = record.output_dim
    train = [(a[:, :m], a[:, m:]) for a in record.train_parts]
    return fit_cubic_narx(train, p, q, c, record.path, moments=record.fit())


def recipe_reads(record: RecordedData) -> bool:
    """Whether the records recipe can train on `record`: it has inputs and complete outputs (its
    least-squares feature and the held-out check against the fitted linear models need both)."""
    return record.input_dim > 0 and not record.num_missing


def gaps_turn_off_recipe(
    data: TrainingRecords | None, overrides: list[str], chosen: bool, init: str | None
) -> int:
    """The missing outputs of the record `data` where they alone keep the records recipe off (no source,
    --preset, --init or feature override chose the model; the record has inputs): its least-squares feature
    and the held-out check against `mop fit arx` need complete outputs. 0 where the recipe applies or
    something else turned it off."""
    if data is None or chosen or init is not None:
        return 0
    if any(k in parse_overrides(list(overrides)) for k in FEATURE_KEYS):
        return 0
    if any(r.u is None for r in data.records):
        return 0
    return int(sum(np.isnan(r.y).sum() for r in data.records))


def with_recorded_features(
    config: RunConfig,
    record: RecordedData | None,
    overrides: list[str],
    chosen: bool = False,
    budget: float = DEFAULT_BUDGET_MINUTES,
) -> RunConfig:
    """Layer 3: the records recipe on recorded data with inputs and complete outputs (`record`: config.data's
    records split as it asks; None without data), unless the source or --preset (`chosen`), the base's
    feature or an override chose the feature (overrides of sizes and steps apply on top of it, as layer 4)."""
    named = parse_overrides(overrides)
    if record is None or chosen or config.model.rls_order > 0:
        return config
    if any(k in named for k in FEATURE_KEYS):
        return config
    if not recipe_reads(record):
        return config
    body = {} if "model.arch" in named else records_body(record)
    arch = named.get("model.arch", body.get("model.arch", config.model.arch))
    cubes = "model.rls_cubes" not in named
    windows = {key: named[key] for key in WINDOW_KEYS if key in named}  # the budget buys the windows trained
    planned = apply_settings(config, {**body, **windows})
    plan = plan_records(record.training_part, planned, budget, cubes, feature=reads_features(arch))
    if body and not {"model.width", "train.steps"} & set(named):  # the planned steps' rest buys width
        body = {**body, "model.width": plan.budget.width(int(body["model.width"]))}
    return apply_settings(config, {**plan.settings(), **body})


def records_body(record: RecordedData) -> dict[str, object]:
    """RECORDS_BODY (mop.recipe.plan) with its windows: RECORDS_HORIZON steps, or as many as the record's
    longest training part holds (and its longest held-out trajectory, where whole trajectories are held
    out: a held-out tail of a record split in time is simulated after the steps before it)."""
    longest = [max(len(a) for a in record.train_parts)]
    if record.split != "time":
        longest.append(max(len(a) for a in record.val_parts))
    horizon = max(1, min(RECORDS_HORIZON, *(n - 1 for n in longest)))
    after = min(RECORDS_BODY["train.simulate_after"], horizon - 1)
    return {**RECORDS_BODY, "train.horizon": horizon, "model.context": horizon, "train.simulate_after": after}


def body_line(
    config: RunConfig, overrides: list[str], init: str | None, chosen: bool, record: RecordedData
) -> str | None:
    """One line naming the records recipe's own network (RECORDS_BODY) where it trains one: no source,
    --preset, --init or model.arch chose the model, and the recipe reads the record."""
    if chosen or init is not None or "model.arch" in parse_overrides(list(overrides)):
        return None
    if config.model.arch != RECORDS_BODY["model.arch"] or not recipe_reads(record):
        return None
    m, t = config.model, config.train
    reads = " and its least-squares feature's free run" if config.data.reads_feature_run else ""
    return (
        f"network: the records recipe's deep LRU ({m.num_layers} x {m.width}), trained on its free-run "
        f"simulation error: in each window of {t.horizon} steps the outputs from a random step >= "
        f"{t.simulate_after} on are read as missing and simulated from the inputs{reads}; the held-out "
        "check then scores it beside the least-squares models (data.feature_input=none: the network "
        "alone; model.arch=gpt: the transformer reading the ARX feature instead)"
    )


def feature_line(config: RunConfig) -> str | None:
    """One line naming the input feature a records run reads, or None without one."""
    m = config.model
    if config.data is not None and config.data.reads_feature_run:
        return (
            "feature: the network reads the free run of the records recipe's least-squares feature (fitted "
            "on the training part: RUN/feature) as inputs, and predicts its residual"
        )
    if m.rls_order == 0:
        return None
    kind = f"ARX({m.rls_order}, {m.arx_order})" if m.arx_order else f"RLS-AR({m.rls_order})"
    if m.rls_cubes:
        kind = f"cubic NARX ({kind} with the cubes of its first {m.rls_cubes} output lags)"
    start = " started from its least-squares fit on the training part" if m.rls_prior != "none" else ""
    if m.rls_fixed:
        start = " fixed at its least-squares fit on the training part"
    offset = " with an intercept" if m.rls_offset else ""
    return (
        f"feature: the network reads the {kind}{offset} one-step prediction{start}, and predicts its residual"
    )


def order_line(
    config: RunConfig, overrides: list[str], init: str | None = None, chosen: bool = False
) -> str | None:
    """One line saying which rule chose the ARX feature's orders of a run on recorded data (None without an
    ARX feature): `mop fit arx` scores the orders on the whole record, the records recipe on its training
    part only (its held-out part must stay unseen), a fine-tune on the whole record; so the three can
    differ on the same record. chosen: the source or --preset chose the config (no records recipe)."""
    m = config.model
    if config.data is None or m.rls_order == 0 or m.arx_order == 0:
        return None
    orders = f"ARX({m.rls_order}, {m.arx_order})"
    if any(k in parse_overrides(list(overrides)) for k in ("model.rls_order", "model.arx_order")):
        return f"orders: {orders}, as the key=value overrides name them"
    rule = "the orders `mop fit arx` chooses (free-run simulation of the last 20% of each trajectory)"
    if init is not None:
        if m.rls_prior == "fit" and m.rls_cubes:
            cubed = f"{m.rls_cubes} cubed output lags"
            return f"orders: {orders} with {cubed}, the source model's (--init {init})"
        if m.rls_prior == "fit" and m.rls_order == m.arx_order and m.rls_order in LONG_ORDERS:
            return (
                f"orders: {orders}, longer than `mop fit arx {config.data.path}` searches: of its orders and "
                f"ARX(P, P), P in {', '.join(map(str, LONG_ORDERS))}, the one that simulates the last 20% of "
                "the training part best (mop.identify.long_arx)"
            )
        if m.rls_prior == "fit":
            return f"orders: {orders}, {rule} on the whole record, as `mop fit arx {config.data.path}` does"
        return f"orders: {orders}, the source model's (--init {init})"
    if not chosen and m.rls_prior == "fit":
        if m.rls_cubes:
            return (
                f"orders: {m.rls_order} output lags ({m.rls_cubes} of them also cubed) "
                f"and {m.arx_order} input "
                f"lags: from {rule} on the training part, the cubic NARX with up to {EXTRA_LAGS} more output "
                "lags that simulates the last 20% of that part best, clearly better than every linear one, "
                "and stays bounded when driven twice as hard (mop.identify.cubic)"
            )
        if m.rls_order == m.arx_order and m.rls_order in LONG_ORDERS:
            return (
                f"orders: {orders}, longer than `mop fit arx` searches (up to 10): of its orders and "
                f"ARX(P, P), P in {', '.join(map(str, LONG_ORDERS))}, the one that simulates the last 20% of "
                "the training part best (mop.identify.long_arx), fitted on the rest; windows of "
                f"{config.train.horizon} steps"
            )
        return (
            f"orders: {orders}, {rule} on the training part only (the held-out part stays unseen), so they "
            f"can differ from `mop fit arx` on the whole record"
        )
    return f"orders: {orders}, as the config sets them"
