"""The one interface every predictor answers, classical or learned, and the registry that names them.

A predictor maps a batch of trajectories to one-step predictions:
    yhat = predictor.predict(traj)          # (B, T+1, m)
where yhat[:, t] predicts y[:, t] using only y[:, :t] and u[:, :t] (plus the system's parameters in
traj.params for predictors that know the system, e.g. the Kalman filter). yhat[:, 0] uses no data.
Predictors with a Gaussian predictive distribution also answer
    mean, var = predictor.predict_distribution(traj)      # each (B, T+1, m), var the diagonal

Registering a predictor is one decorator in its own module:

    @PREDICTORS.register("my-filter", needs_system=True, gaussian=True)
    class MyFilter: ...

Metadata: the keys of PREDICTOR_KEYS, no others (a misspelt key is refused where it is registered and
where it is read).

Options: make_predictor(name, **options) refuses an option the predictor's constructor does not take, so
`make_predictor("pf", num_particle=10)` is an error, not 1000 particles. A caller handing the same options to
many predictors (an experiment's seed) passes them as `shared=`, of which each predictor takes the ones it
accepts.
"""

from __future__ import annotations

import inspect
from collections.abc import Iterable, Mapping
from typing import Any, Protocol, runtime_checkable

from torch import Tensor

from mop.errors import MopError
from mop.memory import check_allocation
from mop.registry import Registry
from mop.systems.base import Trajectories


@runtime_checkable
class Predictor(Protocol):
    name: str

    def predict(self, traj: Trajectories) -> Tensor:
        """(B, T+1, m) one-step predictions, yhat[:, t] from y[:, :t] (and u[:, :t])."""
        ...


# Filled by the modules that define predictors: mop.filters (classical), mop.runs (learned, one per model
# architecture); `import mop` imports both. Plugins: the entry points of the group mop.predictors.
PREDICTOR_KEYS = {
    "needs_system": "reads traj.params: it knows the system",
    "needs_family": "is built with the family the systems come from (an experiment gives it; not data alone)",
    "gaussian": "has predict_distribution",
    "learned": "resolves a trained run directory (mop.runs.register_learned adds one)",
    "arch": "a learned predictor's model architecture",
    "linear_model": "also runs on any linear-Gaussian model given as arrays (mop predict)",
    "default_reference": "the predictor an experiment's MSE ratios divide by when it names none (the KF)",
    "default_panel": "drawn in the error panel of an experiment that names no panel (RLS)",
    "preset_options": "{preset: {option: value}}: options the experiments give it under that preset",
    "skip_presets": "presets whose experiments leave it out unless asked for (--with NAME)",
}
PREDICTORS: Registry = Registry("predictor", group="mop.predictors", keys=PREDICTOR_KEYS)


def accepted_options(name: str) -> list[str] | None:
    """The options predictor `name`'s constructor takes (None: any, it takes **kwargs)."""
    params = inspect.signature(PREDICTORS.get(name)).parameters
    if any(p.kind is p.VAR_KEYWORD for p in params.values()):
        return None
    return [k for k, p in params.items() if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]


def make_predictor(name: str, shared: Mapping[str, Any] | None = None, **options: Any) -> Predictor:
    """The registered predictor `name` built with `options`; MopError for an option it does not take.

    shared: options offered to many predictors at once (e.g. an experiment's seed): only those the
    predictor accepts are passed; `options` override them. E.g. make_predictor("pf", seed=3);
    make_predictor("mop", run_dir="runs/x") for a learned one, or run_dir="pretrained:linear" for a
    model shipped with mop (mop.pretrained).
    """
    factory, accepted = PREDICTORS.get(name), accepted_options(name)
    unknown = [k for k in options if accepted is not None and k not in accepted]
    if unknown:
        raise MopError(
            f"predictor {name!r} takes no option {', '.join(map(repr, unknown))}; "
            f"it accepts: {', '.join(accepted) or 'no options'}"
        )
    offered = {k: v for k, v in (shared or {}).items() if accepted is None or k in accepted}
    predictor = factory(**{**offered, **options})
    predictor.name = name
    return predictor


def is_learned(name: str) -> bool:
    return bool(PREDICTORS.meta(name).get("learned"))


def needs_system(name: str) -> bool:
    return bool(PREDICTORS.meta(name).get("needs_system"))


def first_learned(names: Iterable[str]) -> str:
    """The first learned predictor among `names` (the model an experiment is about); MopError if none."""
    for name in names:
        if name in PREDICTORS and is_learned(name):
            return name
    raise MopError(f"no learned predictor among {', '.join(names)}; add one (e.g. a trained model)")


def forecast(predictor: Predictor, traj: Trajectories, steps: int, start: int = 0) -> Tensor:
    """k-step-ahead forecasts (B, T+1, K, m), K = steps, of a predictor with a `forecast` method.

    forecast[:, t, j] predicts y_{t+j} from y_0..y_{t-1} (and the inputs u_0..u_{t+j-1}, given where the
    family has inputs); j = 0 is the one-step predict(traj)[:, t]. Entries whose target index t + j exceeds T
    are NaN, and so are those of origins t < start: a predictor whose `forecast` takes `start` skips their
    roll-outs (the particle filter does), the others compute them and they are dropped. Each predictor
    documents how it rolls out (filters: their time update with no measurement;
    RLS / subspace: iterating the fitted model; learned: autoregressively on their own predictions, or with
    model.forecast_mode = "gap" by reading the future outputs as missing).
    """
    if not isinstance(steps, int) or steps < 1:
        raise MopError(f"forecast steps must be an integer >= 1, got {steps!r}")
    method = getattr(predictor, "forecast", None)
    if not callable(method):
        raise MopError(
            f"predictor {getattr(predictor, 'name', type(predictor).__name__)!r} has no k-step forecast; "
            "use --steps 1 (one-step predict) or another predictor"
        )
    B, T1, m = traj.y.shape
    if not isinstance(start, int) or not 0 <= start <= T1 - 1:
        raise MopError(f"forecast start must be an integer origin in [0, T = {T1 - 1}], got {start!r}")
    check_allocation(  # the output and one working copy of it
        2 * B * T1 * steps * m * traj.y.element_size(),
        f"a {steps}-step forecast of {B} trajectories x {T1} steps",
        "forecast fewer steps or fewer trajectories at a time",
    )
    takes_start = "start" in inspect.signature(method).parameters
    out = nan_beyond_horizon(
        method(traj, steps, start=start) if takes_start and start else method(traj, steps)
    )
    if start:
        out[:, :start] = float("nan")
    return out


def simulate(predictor: Predictor, traj: Trajectories, context: int) -> Tensor:
    """Free-run simulation (B, T+1-c, m), c = context: out[:, j] predicts y_{c+j} from y_0..y_{c-1} and the
    inputs u_0..u_{c+j-1} alone, with no output after the context (the system-identification metric).

    It is the k-step forecast from origin c, forecast[:, c, j]; a predictor may answer it directly with a
    `simulate(traj, context)` method (the filters and learned models do: one rollout instead of one from
    every origin). c = 0 simulates from the record's start with y_0 its initial condition, as c = 1 and
    `mop predict --simulate 0` do: (B, T, m), y_1..y_T. MopError unless 0 <= c <= T and the predictor has a
    forecast or a simulate.
    """
    T = traj.horizon
    if not isinstance(context, int) or not 0 <= context <= T:
        raise MopError(f"simulation context must be an integer in [0, T = {T}], got {context!r}")
    context = max(context, 1)
    method = getattr(predictor, "simulate", None)
    if callable(method):
        return method(traj, context)
    return forecast(predictor, traj, T + 1 - context)[:, context]


def nan_beyond_horizon(f: Tensor) -> Tensor:
    """f (B, T+1, K, m) with the entries whose target index t + j > T set to NaN (in place; returned)."""
    T1, K = f.shape[1], f.shape[2]
    for j in range(1, K):
        f[:, max(T1 - j, 0) :, j] = float("nan")
    return f


def repeat_forecast(yhat: Tensor, steps: int) -> Tensor:
    """(B, T+1, K, m) forecasts that repeat the one-step prediction yhat (B, T+1, m) for every horizon."""
    return nan_beyond_horizon(yhat[:, :, None].expand(-1, -1, steps, -1).clone())
