"""A test record simulated with an estimation record as the model's in-context data (mop predict --context).

simulate_with_context(predictor, test, init, context) -> InContext: its simulation (T - init, m) holds
ysim_init..ysim_{T-1} of the test record, from its first `init` measured outputs and its inputs, after the
model has read the context records. There are three readings:

- "none": the test alone, as without --context.
- "window": one trajectory, the last context record's last part followed by the test, simulated from the
  test's step `init` (exactly the by-hand concatenation of that part and the test, `mop predict
  --simulate L + init` on it). A learned model that reads at most C inputs (its trained context) gets the
  last C - init steps, so that its first window holds them and the test's init window; a predictor without
  a limit gets all of it.
- "fit": for a class model whose in-context identifier is its ARX / NARX feature (model.record_norm =
  "causal" with model.rls_order > 0), the context however long, in a summary: the feature's coefficients
  fitted by least squares over every context record (the sufficient statistics a window of C steps would
  accumulate, over all of them), in the units of the context's mean and std. The model then reads the test
  with its feature starting from those coefficients (model.rls_prior, as a fine-tune of the class model
  starts at step 0, mop.recipe.finetune.with_record_prior), and its network's correction at a gain g of
  GAINS: 0, the fitted feature alone, or 1, the class model as trained (two whole models, as the records
  recipe's held-out check weighs). So the model's context is the whole estimation record, not its last C
  steps, with no training. Where the context is long
  enough to support a longer linear ARX than the model's own (context_orders: the records recipe's rule,
  mop.identify.long_arx), the readings "fit ARX(P, P) gain G" fit that one instead (the network reads the
  feature's prediction, whatever its orders); where it is too short for that, "fit ARX(p, q) gain G" read
  it with the orders `mop fit arx` picks on it (on the real cascaded tanks ARX(2, 10) where the class
  models' own is ARX(10, 10)).
- "units": for a records start without a feature (pretrained:cascaded-tanks-lru: the records recipe's deep
  LRU, pretrained with each window after its estimation record, in that record's units), the test read in
  the units of the context's mean and std (context_normalization), as it trained: the context gives the
  plant's scale, the network the rest.

Which reading: each is measured on the context itself before the test is touched. The last context
record's last H steps (H = min(len / 4, 2000)) are simulated from their first `init` outputs after the
rest of the context read each way ("fit" fitted without those H steps); the reading with the lowest RMSE
there simulates the test (`choose=True`, the default; "none" among them and first on ties, so a reading is
used only where it simulated that held-out end at least as well as the test alone). A reading whose
simulation of the test strays more than STRAY_FACTOR ranges beyond the outputs measured before it (the
context's and the test's first `init`; mop.records.divergence_step) gives way to the next best: a cubic
feature fitted on one F-16 record left every range on another (5.6e5 m/s^2), and on held-out Duffing
oscillators the NARX a 500-step held-out end chose simulated 2 of 40 tests 40-50 ranges away (mean RMSE
7.5 test stds against 0.84 for the model as trained). Where every reading strays, the best-scored one that
stays within mop.records.DIVERGENCE_FACTOR ranges (else the best-scored) simulates the test. The scores
are returned beside the simulation. With `choose=False` the reading is "window" (the concatenation).

A single-output class model reads a record of several outputs one output at a time: each output channel
with all the inputs is a single-output record of the same plant, read and simulated as above, and the
simulations are put side by side (by_channel; on the F-16's three accelerations, one force input). Each
channel then misses the other outputs' lags; the line names the shipped models of the record's widths that
read them all (pretrained:lti-mimo for three outputs and one input).

The seam: at the join of "window" the record jumps from the context's last state to the test's first; the
held-out check reads across the same kind of seam, one record earlier.
"""

from __future__ import annotations

import copy
import dataclasses
import re
from collections.abc import Sequence

import numpy as np
import torch

from mop.errors import MopError
from mop.filters.arx import least_squares_coefficients
from mop.identify.arx import ARX
from mop.identify.long_arx import choose_long_orders
from mop.identify.select import fit as fit_identifier
from mop.models.normalization import Normalization
from mop.models.predictor import LearnedPredictor
from mop.models.registry import build_model
from mop.pretrained import fitting
from mop.recipe.finetune import RECORD_PRIOR_STEPS
from mop.recipe.shrink import scale_correction
from mop.record import Record
from mop.records import divergence_step, simulate_all, simulation_rmse
from mop.runs import load_config
from mop.train.context import LEAST_SQUARES_RIDGE

# the "fit" readings' gains: the fitted feature alone (0) or the class model as trained (1). The gains
# between (0.25, 0.5, 0.75: mop.recipe.shrink.GAINS, which a fine-tuned transformer's check still weighs)
# were retired: on 40 held-out Duffing oscillators (scripts/in_context_class.py) the reading chosen from
# these two simulated the tests at a mean RMSE / std of 0.753 (median 0.901) against 0.808 (0.903) with
# all five; on the real cascaded tanks and Silverbox every test read "fit gain 0" either way (the same
# RMSE), and on the F-16 the ARX(40, 40) at gain 0 instead of 0.25 gave 0.2476 / 0.3811 / 0.4936 m/s^2
# both ways (to 1e-4)
GAINS = (0.0, 1.0)
HELD_OUT_MAX = 2000  # the held-out end of the context: at most this many steps, at most a quarter of it
# a reading whose simulation of the test leaves the measured outputs by more than this many of their ranges
# gives way to the next best (the test itself left them by at most 0.08 ranges on 40 held-out Duffing
# oscillators; the readings that gave way 0.8-48)
STRAY_FACTOR = 0.5
# the orders `mop fit arx` picks are searched on contexts up to this many steps: its grid of 100 fits and
# free runs took about 1 s on the cascaded tanks' 1024 steps and 268 s on the F-16's 294,912 (whose context
# supports the longer ARX anyway)
SEARCH_MAX_STEPS = 20000
# `mop fit arx`'s largest orders: a "fit ARX(p, q)" reading of orders up to these is the ARX it fits (the
# longer ARX starts at mop.identify.long_arx.LONG_ORDERS[0] = 15), fitted as it fits them: the minimum-norm
# least squares, not the ridge of the class models' own fits (relative 1e-6). On the real cascaded tanks the
# ten nearly collinear input lags of ARX(2, 10) simulated the test at 0.6299 V with that ridge, 0.6143 V
# without (`mop fit arx`'s). The longer ARX keeps the ridge: without it, on the F-16's long context,
# ARX(40, 40) diverged on Level 6
SEARCH_MAX_ORDER = 10


@dataclasses.dataclass(frozen=True)
class InContext:
    """A simulation of the test record and how the context was read."""

    simulation: np.ndarray  # (T - init, m)
    reading: str  # "none", "window" or "fit gain G"
    context_steps: int  # steps of the context read before the test (0: none; "fit": all of them)
    held_out: dict[str, float]  # each reading's RMSE on the context's held-out end ({}: not measured)
    diverged: tuple[str, ...] = ()  # better-scored readings whose test simulation strayed (STRAY_FACTOR)
    shipped: tuple[str, ...] = ()  # read one output at a time: the shipped models that read them all at once


def context_limit(predictor) -> int | None:
    """How many inputs the predictor reads at most (a context-limited learned model's C), else None."""
    model = getattr(predictor, "model", None)
    if model is not None and getattr(model, "context_limited", False):
        return int(model.cfg.context)
    return None


def check_context(test: Record, context: Sequence[Record]) -> None:
    """One-line MopError where the context does not fit the test record: no context, other widths, another
    sampling time (where both are known)."""
    if not context:
        raise MopError("--context: the file holds no record")
    for r in context:
        if (r.num_outputs, r.num_inputs) != (test.num_outputs, test.num_inputs):
            raise MopError(
                f"--context record {r.name!r} has {r.num_outputs} outputs and {r.num_inputs} inputs, the "
                f"test record {test.num_outputs} and {test.num_inputs}; give the same plant's channels"
            )
        if r.sampling_time and test.sampling_time and not np.isclose(r.sampling_time, test.sampling_time):
            raise MopError(
                f"--context record {r.name!r} is sampled every {r.sampling_time:g} s, the test every "
                f"{test.sampling_time:g} s; resample one of them"
            )
        if np.isnan(r.y).any():
            raise MopError(
                f"--context record {r.name!r} has missing outputs; give a complete record as context"
            )


def fits_context(predictor) -> bool:
    """Whether the "fit" reading serves the predictor: a learned class model (record_norm "causal"), or one
    trained with each window read after its estimation record's fit (train.context_prefix: a records start
    such as pretrained:duffing-records, which the "fit" reading reads exactly as it trained), whose feature
    is an ARX / NARX identifier without coefficients of its own (model.rls_prior not a list)."""
    cfg = getattr(predictor, "cfg", None)
    return (
        isinstance(predictor, LearnedPredictor)
        and cfg is not None
        and (cfg.record_norm == "causal" or trained_on_fits(predictor))
        and cfg.rls_order > 0
        and not isinstance(cfg.rls_prior, list)
        and hasattr(predictor.model, "read_out")
    )


def reads_context_units(predictor) -> bool:
    """Whether the "units" reading serves the predictor: a learned model without a feature
    (model.rls_order = 0) that trained each window in its estimation record's units (train.context_prefix,
    no record_norm): a records start of the records recipe's deep LRU."""
    cfg = getattr(predictor, "cfg", None)
    return (
        isinstance(predictor, LearnedPredictor)
        and cfg is not None
        and cfg.record_norm == "none"
        and cfg.rls_order == 0
        and trained_on_fits(predictor)
    )


def in_context_units(predictor: LearnedPredictor, context: Sequence[Record]) -> LearnedPredictor:
    """The predictor reading records in the units of the context's mean and std (the same model)."""
    norm = context_normalization(context)
    return LearnedPredictor(predictor.model, name=predictor.name, mode=predictor.mode, normalization=norm)


def trained_on_fits(predictor: LearnedPredictor) -> bool:
    """Whether the run the predictor was loaded from (its source) trained each window after its estimation
    record's least-squares fit (train.context_prefix > 0, mop.train.context)."""
    source = getattr(predictor, "source", "")
    if not source:
        return False
    try:
        return load_config(source).train.context_prefix > 0
    except (MopError, OSError):
        return False


def context_normalization(context: Sequence[Record]) -> Normalization:
    """Each channel's mean and std over every context record (std 0 -> 1): the units the fit holds in."""
    y = np.concatenate([r.y for r in context])
    u = np.concatenate([r.u for r in context]) if context[0].u is not None else np.zeros((len(y), 0))
    std = lambda a: np.where(a.std(axis=0) > 0, a.std(axis=0), 1.0)  # noqa: E731
    t = lambda a: torch.from_numpy(np.asarray(a, dtype=np.float64))  # noqa: E731
    return Normalization(t(y.mean(axis=0)), t(std(y)), t(u.mean(axis=0)), t(std(u)))


def _normalised(context: Sequence[Record]) -> list[np.ndarray]:
    """Each context record (L, m + k) in context_normalization's units."""
    norm = context_normalization(context)
    joined = lambda r: r.y if r.u is None else np.concatenate([r.y, r.u], axis=1)  # noqa: E731
    return [norm.inputs(torch.from_numpy(joined(r).astype(np.float64))[None])[0].numpy() for r in context]


def context_orders(predictor, context: Sequence[Record]) -> tuple[int, int] | None:
    """Other orders (p, q) for the class model's linear ARX feature, read from the context:
    - where the context is long enough for a longer ARX(P, P), that one if it simulates the held-out end of
      the context records better (the records recipe's rule, mop.identify.long_arx.choose_long_orders, P at
      most half the model's context);
    - where it is too short for any (and at most SEARCH_MAX_STEPS steps), the orders `mop fit arx` picks on
      it (mop.identify.select.fit: its grid up to ARX(10, 10), scored by simulating each record's last 20%).
    None where those are the model's own, and for a cubic feature or one without inputs."""
    cfg = getattr(predictor, "cfg", None)
    if not fits_context(predictor) or cfg.rls_cubes or cfg.arx_order == 0:
        return None
    m = cfg.output_dim
    parts = [(a[:, :m], a[:, m:]) for a in _normalised(context)]
    orders = (cfg.rls_order, cfg.arx_order)
    p, q, scores = choose_long_orders(parts, *orders, max_order=cfg.context // 2)
    if not scores and sum(len(r) for r in context) <= SEARCH_MAX_STEPS:
        try:
            pairs = [r.pair for r in context]
            found = fit_identifier(ARX.kind, pairs, max_order=SEARCH_MAX_ORDER, source="the context").orders
        except MopError:  # too short for the grid, or every order diverged: the model's own
            return None
        p, q = found["p"], found["q"]
    return None if (p, q) == orders else (p, q)


def fitted_to_context(
    predictor: LearnedPredictor,
    context: Sequence[Record],
    gain: float = 1.0,
    orders: tuple[int, int] | None = None,
):
    """The class model with its feature's coefficients fitted by least squares on every context record
    (in context_normalization's units) and its correction times `gain` (see the module docstring): a new
    LearnedPredictor in the data's units; the predictor given is not changed. orders: the feature's (p, q)
    instead of the model's own (context_orders; its input is the feature's prediction whatever its orders),
    which then stays at its fit (model.rls_fixed, as the records recipe's and a fine-tune's long ARX): from
    P_0 = I the test's first outputs would move its many coefficients (a three-output ARX(40, 40) has 161 an
    output) away from the fit over the whole context; on the F-16's three accelerations that simulated the
    context's held-out end at 9.3 m/s^2 against 1.15 for the model's own orders). At gain 0 the feature's
    free run is held within the range of the context's outputs and the record's (with_context_range), not
    the record's alone. At gain 0 the reading is the fitted ARX / NARX itself,
    and the record's first outputs may span a fraction of the plant's range (the real cascaded tanks: held
    at 7.3 V while the level rose to 10 V; test RMSE 0.853 V, the same fit unbounded 0.630). With the
    network's correction the feature stays bounded as the class model was trained, by its window's outputs:
    on 40 held-out Duffing oscillators the context's range at gain 1 raised the mean RMSE / std from 0.84 to
    1.32 (scripts/in_context_class.py)."""
    cfg, norm = predictor.cfg, context_normalization(context)
    if orders is not None:
        cfg = dataclasses.replace(cfg, rls_order=orders[0], arx_order=orders[1])
    searched = orders is not None and max(orders) <= SEARCH_MAX_ORDER  # `mop fit arx`'s orders, its fit
    theta = least_squares_coefficients(
        _normalised(context),
        cfg.output_dim,
        cfg.rls_order,
        cfg.arx_order,
        cfg.rls_offset,
        cfg.rls_cubes,
        ridge=0.0 if searched else LEAST_SQUARES_RIDGE,
    )
    fitted = dataclasses.replace(
        cfg,
        rls_prior=[float(v) for v in theta.reshape(-1)],
        rls_prior_cov=None,
        rls_p0=1.0,
        rls_fixed=orders is not None,
        record_prior_steps=RECORD_PRIOR_STEPS if cfg.record_norm == "causal" else 0,
    )
    return at_gain(_rebuilt(predictor, fitted, norm), context, gain)


def at_gain(fitted: LearnedPredictor, context: Sequence[Record], gain: float) -> LearnedPredictor:
    """A predictor fitted to `context` at gain 1, its correction times `gain`; at gain 0 (the fitted feature
    alone) its free run also held within the context's outputs (with_context_range)."""
    return with_context_range(fitted, context) if gain == 0 else with_gain(fitted, gain)


def with_context_range(fitted: LearnedPredictor, context: Sequence[Record]) -> LearnedPredictor:
    """A predictor fitted to `context` (fitted_to_context, gain 0 or 1) at gain 0, its feature's free run
    held within the context's outputs too (model.rls_fill_range, in the fit's units)."""
    m = fitted.cfg.output_dim
    outputs = np.concatenate([a[:, :m] for a in _normalised(context)])
    bounds = [*map(float, outputs.min(0)), *map(float, outputs.max(0))]
    cfg = dataclasses.replace(fitted.cfg, rls_fill_range=bounds)
    return with_gain(_rebuilt(fitted, cfg, fitted.normalization), 0.0)


def _rebuilt(predictor: LearnedPredictor, cfg, normalization) -> LearnedPredictor:
    """predictor's weights in a model built from cfg (its architecture's), on the same device and dtype."""
    weights = next(predictor.model.parameters())
    model = build_model(cfg).to(device=weights.device, dtype=weights.dtype)
    model.load_state_dict(predictor.model.state_dict())
    return LearnedPredictor(
        model.eval(), name=predictor.name, mode=predictor.mode, normalization=normalization
    )


def with_gain(predictor: LearnedPredictor, gain: float) -> LearnedPredictor:
    """The predictor with its correction times `gain` (a copy of its model; the same predictor at 1)."""
    if gain == 1.0:
        return predictor
    model = copy.deepcopy(predictor.model)
    scale_correction(model, gain)
    return LearnedPredictor(
        model, name=predictor.name, mode=predictor.mode, normalization=predictor.normalization
    )


def _joined(first: Record, second: Record) -> Record:
    u = None if first.u is None else np.concatenate([first.u, second.u])
    return Record(y=np.concatenate([first.y, second.y]), u=u, name=second.name)


def _simulate(predictor, record: Record, start: int) -> np.ndarray:
    return simulate_all(predictor, [record.pair], start)[0]


def _rmse(y: np.ndarray, sim: np.ndarray) -> float:
    return simulation_rmse(y, sim)[0]


def _window(predictor, test: Record, init: int, source: Record) -> tuple[np.ndarray, int]:
    """The "window" reading: (simulation, steps of the context read)."""
    limit = context_limit(predictor)
    keep = len(source) if limit is None else max(limit - init, 0)
    tail = source[len(source) - min(keep, len(source)) :]
    if len(tail) == 0:
        return _simulate(predictor, test, init), 0
    return _simulate(predictor, _joined(tail, test), len(tail) + init), len(tail)


def _read(
    predictor, test: Record, init: int, context: Sequence[Record], reading: str, fitted=None
) -> tuple[np.ndarray, int]:
    """(simulation of test from init, context steps read) for one reading; fitted: {orders: the predictor
    fitted to this context at gain 1 (fitted_to_context)}, filled in as they are made."""
    if reading == "none":
        return _simulate(predictor, test, init), 0
    if reading == "window":
        return _window(predictor, test, init, context[-1])
    if reading == "units":
        return _simulate(in_context_units(predictor, context), test, init), sum(len(r) for r in context)
    fitted = {} if fitted is None else fitted
    orders, gain = reading_orders(reading), float(reading.rpartition(" ")[2])
    if orders not in fitted:
        fitted[orders] = fitted_to_context(predictor, context, orders=orders)
    return _simulate(at_gain(fitted[orders], context, gain), test, init), sum(len(r) for r in context)


def _with_orders(reading: str, orders: tuple[int, int] | None) -> str:
    """A "fit ARX(P, Q) gain G" reading with the orders `orders` instead (None: the model's own, "fit gain
    G"); other readings as they are. The held-out check chooses how to read the context (its orders read
    on the context before the held-out end); the test is read that way from the whole context: the orders
    too (on the real cascaded tanks `mop fit arx` picks ARX(1, 9) on the first 768 steps, ARX(2, 10) on all
    1024; test 0.6377 against 0.6143 V)."""
    if reading_orders(reading) is None:
        return reading
    gain = reading.rpartition(" ")[2]
    return f"fit gain {gain}" if orders is None else f"fit ARX({orders[0]}, {orders[1]}) gain {gain}"


def reading_orders(reading: str) -> tuple[int, int] | None:
    """The feature's orders a "fit ARX(P, Q) gain G" reading names; None for "fit gain G" (the model's)."""
    found = re.match(r"fit ARX\((\d+), (\d+)\)", reading)
    return None if found is None else (int(found[1]), int(found[2]))


def readings(predictor, orders: tuple[int, int] | None = None) -> list[str]:
    """The readings a predictor can take, in their order of preference on ties; orders: context_orders's,
    whose "fit ARX(p, q) gain G" readings come last."""
    fit = [f"fit gain {g:g}" for g in GAINS] if fits_context(predictor) else []
    named = [] if orders is None or not fit else [f"fit ARX({orders[0]}, {orders[1]})"]
    long = [f"{name} gain {g:g}" for name in named for g in GAINS]
    units = ["units"] if reads_context_units(predictor) else []
    return ["none", "window", *units, *fit, *long]


def simulate_with_context(
    predictor, test: Record, init: int, context: Sequence[Record], choose: bool = True
) -> InContext:
    """The test record simulated after the context (see the module docstring)."""
    check_context(test, context)
    if not 1 <= init < len(test):
        raise MopError(f"the test's initialization window {init} must be in [1, {len(test) - 1}]")
    context = list(context)
    if by_channel(predictor, test):
        return _by_channel(predictor, test, init, context, choose)
    if not choose:
        sim, steps = _read(predictor, test, init, context, "window")
        return InContext(sim, "window", steps, {})
    source, scores = context[-1], {}
    h = min(len(source) // 4, HELD_OUT_MAX)
    if h > init + 1:
        end = source[len(source) - h :]
        before = [*context[:-1], source[: len(source) - h]]
        fitted = {}
        for reading in readings(predictor, context_orders(predictor, before)):
            scores[reading] = _rmse(end.y, _read(predictor, end, init, before, reading, fitted)[0])
    ranked = sorted(scores, key=lambda r: (scores[r], list(scores).index(r))) or ["none"]
    if any(reading_orders(r) is not None for r in ranked):  # orders read on the whole context, as its fit
        whole = context_orders(predictor, context)
        ranked = list(dict.fromkeys(_with_orders(r, whole) for r in ranked))
    seen = np.concatenate([*(r.y for r in context), test.y[:init]])  # the outputs measured before the run
    dropped, fitted, sims = [], {}, {}
    for reading in ranked:
        sims[reading] = _read(predictor, test, init, context, reading, fitted)
        if divergence_step(seen, sims[reading][0], STRAY_FACTOR) is None:
            sim, steps = sims[reading]
            return InContext(sim, reading, steps, scores, tuple(dropped))
        dropped.append(reading)
    kept = next((r for r in ranked if divergence_step(seen, sims[r][0]) is None), ranked[0])
    sim, steps = sims[kept]
    return InContext(sim, kept, steps, scores, tuple(r for r in dropped if r != kept))


def by_channel(predictor, test: Record) -> bool:
    """Whether a single-output learned model (a class model) reads each output of a multi-output record on
    its own: every output channel with all the inputs, as a single-output record of the same plant."""
    cfg = getattr(predictor, "cfg", None)
    return cfg is not None and cfg.output_dim == 1 and test.num_outputs > 1


def _channel(record: Record, i: int) -> Record:
    return Record(y=record.y[:, i : i + 1], u=record.u, name=record.name, sampling_time=record.sampling_time)


def _by_channel(predictor, test: Record, init: int, context: list[Record], choose: bool) -> InContext:
    """simulate_with_context of each output channel on its own, the simulations side by side; the readings,
    scores and divergences named by channel (y0, y1, ..)."""
    done = [
        simulate_with_context(predictor, _channel(test, i), init, [_channel(r, i) for r in context], choose)
        for i in range(test.num_outputs)
    ]
    return InContext(
        simulation=np.concatenate([d.simulation for d in done], axis=1),
        reading="; ".join(f"y{i}: {d.reading}" for i, d in enumerate(done)),
        context_steps=max(d.context_steps for d in done),
        held_out={f"y{i} {k}": v for i, d in enumerate(done) for k, v in d.held_out.items()},
        diverged=tuple(f"y{i} {r}" for i, d in enumerate(done) for r in d.diverged),
        shipped=tuple(fitting(test.num_outputs, test.num_inputs)),
    )


def reading_line(done: InContext) -> str:
    """How the context was read, and the evidence: one line for mop predict and mop benchmark."""
    what = {
        "none": "not read",
        "window": f"its last {done.context_steps} steps read before the test",
        "units": f"all {done.context_steps} steps read for their mean and std, the test read in those units",
    }.get(done.reading, "")
    if not what:
        orders = reading_orders(done.reading)
        feature = "the feature's" if orders is None else f"an ARX{orders} feature's"
        what = (
            f"all {done.context_steps} steps read as {feature} fit, correction gain "
            f"{done.reading.rpartition(' ')[2]}"
            if done.reading.startswith("fit")
            else f"each output on its own ({done.reading})"
        )
    if done.diverged:
        what += f" ({', '.join(done.diverged)} strayed beyond the measured outputs on the test)"
    if done.shipped:
        what += f"; {', '.join(done.shipped)} reads every output together, each on all outputs' lags"
    if not done.held_out:
        return what
    scores = ", ".join(f"{k} {v:.4g}" for k, v in done.held_out.items())
    return f"{what} (simulation RMSE on its held-out end: {scores})"
