"""Never worse than the fitted linear models: the choice a records run makes after training.

After a records-recipe run has trained, its network with the correction at each gain of
mop.recipe.shrink.GAINS (1: as trained; 0: its in-context feature alone) and the linear models `mop fit
arx` and `mop fit n4sid` choose on the same training part (LINEAR) simulate the held-out data
(held_out_stretches: the last 10% of a record after the n measured steps before it, or the held-out
trajectories, or --val) from the inputs alone, and are scored by the RMSE of the simulated steps (a
simulation that diverges scores inf: mop.records.divergence_step). n is the records' initialization window
(Record.init_window, as a benchmark's test is simulated) where they give one, else INIT_WINDOW.

The best score wins, unless its free run over a whole record diverges: every record is simulated from its
first n outputs to its end, as long a free run as a test of the record's length asks, and a candidate that
leaves the record's range there (divergence_step) is passed over for the next best. A held-out tail of a
short record is a few hundred steps; a correction that is stable there and diverges at step 400 of a test
is what this catches.
selection.json in the run directory holds every score and the one kept:
- the network at its gain: a gain below 1 is written into the run's weights;
- a linear model otherwise: the run directory also holds it refitted on the whole estimation record,
  exactly what `mop fit KIND FILE` writes (fitted.json), and `mop predict RUN`, `mop.load(RUN)` load it
  (they read a directory with fitted.json as a fitted model),
so a user never gets a run that simulates its held-out data worse than the better linear model would have.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from mop.atomic import write_json
from mop.checkpoint import save_model
from mop.config import RunConfig
from mop.errors import MopError
from mop.identify.arx import ARX
from mop.identify.n4sid import N4SID
from mop.identify.select import fit
from mop.identify.store import FILE as FITTED_FILE
from mop.recipe.shrink import GAINS, gain_scores, scale_correction
from mop.records import divergence_step, simulate_all
from mop.runs import load_predictor
from mop.train.estimate import duration
from mop.train.records import RecordedData

SELECTION_FILE = "selection.json"
INIT_WINDOW = 50  # measured outputs a held-out simulation starts from where the records give none
LINEAR = (ARX.kind, N4SID.kind)  # the fitted linear models the network must beat, preferred in this order
NAMES = {ARX.kind: "ARX", N4SID.kind: "N4SID"}


def simulation_rmse(predictor, data: list[tuple[np.ndarray, np.ndarray]], init: int) -> float:
    """RMSE of y[init:] simulated from y[:init] and the inputs, pooled over the records; inf where the
    simulation turned non-finite (a diverged run is not scored over its finite steps)."""
    return stretches_rmse(predictor, [(y, u, init) for y, u in data])


def stretches_rmse(predictor, stretches: list[tuple[np.ndarray, np.ndarray, int]]) -> float:
    """simulation_rmse of stretches (y, u, init), each simulated after its own first `init` outputs."""
    errors = []
    for y, u, init in stretches:
        sim = simulate_all(predictor, [(y, u)], init)[0]
        if divergence_step(y, sim) is not None:
            return math.inf
        errors.append(y[init:] - sim)
    return float(np.sqrt(np.nanmean(np.concatenate(errors) ** 2)))


def init_window(record: RecordedData) -> int:
    """n, the measured outputs a held-out simulation starts from: the largest initialization window the
    given records name (Record.init_window, e.g. a benchmark's n), else INIT_WINDOW."""
    named = [r.init_window for r in record.given.records if r.init_window > 0]
    return max(named) if named else INIT_WINDOW


def held_out_stretches(
    record: RecordedData, n: int | None = None
) -> list[tuple[np.ndarray, np.ndarray, int]]:
    """(y, u, init) of each held-out stretch: where one record is split in time, its held-out tail after the
    n (init_window) measured steps before it (as a test record is simulated after its initialisation
    window), so every held-out step is scored; held-out records (--val, or whole trajectories) from their
    own first min(n, L/2) outputs."""
    n = init_window(record) if n is None else n
    m = record.output_dim
    pairs = lambda a: (a[:, :m], a[:, m:])  # noqa: E731
    if record.split == "time":
        stretches = []
        for train, val in zip(record.train_parts, record.val_parts, strict=True):
            init = min(n, len(train))
            stretches.append((*pairs(np.concatenate([train[len(train) - init :], val])), init))
        return stretches
    init = max(1, min(n, min(len(a) for a in record.val_parts) // 2))
    return [(*pairs(a), init) for a in record.val_parts]


def diverges_over_records(predictor, record: RecordedData, n: int) -> bool:
    """Whether `predictor`'s free run over a whole given record, from its first n outputs to its end,
    leaves the record's range (mop.records.divergence_step) on any record."""
    for r in record.given.records:
        init = min(n, len(r.y) - 1)
        if divergence_step(r.y, simulate_all(predictor, [(r.y, r.u)], init)[0]) is not None:
            return True
    return False


def _gains_apply(predictor) -> bool:
    """Whether the network's correction can be scaled (mop.recipe.shrink): a transformer with the mean
    read-out reading a feature, whose gain 0 is that feature alone."""
    cfg = getattr(getattr(predictor, "model", None), "cfg", None)
    return cfg is not None and getattr(cfg, "rls_order", 0) > 0 and getattr(cfg, "readout", "") == "mean"


def _fit_linear(train: list, source: str) -> dict:
    """{kind: the fitted model} of LINEAR on the training part; a kind that cannot be fitted there (a
    record too short for N4SID's Hankel matrices) is left out."""
    fitted = {}
    for kind in LINEAR:
        try:
            fitted[kind] = fit(kind, train, source=source)
        except MopError:
            if kind == LINEAR[0]:
                raise
    return fitted


def _at_gain(network, gain: float, action):
    """action() with the network's correction scaled by `gain`, its read-out restored after."""
    kept = {k: v.clone() for k, v in network.model.read_out.state_dict().items()}
    try:
        scale_correction(network.model, gain)
        return action()
    finally:
        network.model.read_out.load_state_dict(kept)


def select_against_linear(run_dir: str | Path, config: RunConfig, record: RecordedData) -> dict:
    """Choose what the finished run in `run_dir` predicts with (see the module docstring): the network with
    its correction at a gain of mop.recipe.shrink.GAINS, or a linear model of LINEAR fitted on the training
    part, by free-run simulation of the held-out data after n measured outputs (init_window), passing over
    a candidate whose free run over a whole record diverges. On a tie the network at the larger gain, then
    the ARX, is kept. Writes SELECTION_FILE; a gain below 1 is written into the run's model.safetensors,
    and where a linear model wins the run also holds it refitted on the whole record (fitted.json, as `mop
    fit KIND` writes it). A run that already holds SELECTION_FILE keeps its choice.
    record: config.data's records in memory, split as it asks (mop.train.records.RecordedData)."""
    run_dir = Path(run_dir)
    done = run_dir / SELECTION_FILE
    if done.is_file():
        previous = json.loads(done.read_text())
        if previous.get("format") == 3:
            return previous
    m = record.output_dim
    train = [(a[:, :m], a[:, m:]) for a in record.train_parts]
    n = init_window(record)
    stretches = held_out_stretches(record, n)
    linear = _fit_linear(train, config.data.path)
    network = load_predictor(run_dir)
    network.model.eval()
    score = lambda: stretches_rmse(network, stretches)  # noqa: E731
    gains = GAINS if _gains_apply(network) else (1.0,)
    by_gain = gain_scores(network.model, score) if len(gains) > 1 else [score()]
    linear_rmse = {kind: stretches_rmse(model, stretches) for kind, model in linear.items()}
    # candidates in order of preference on a tie: the network at the larger gain, then LINEAR's order
    candidates = [("network", g, s) for g, s in sorted(zip(gains, by_gain, strict=True), reverse=True)]
    candidates += [(kind, None, linear_rmse[kind]) for kind in linear]
    ranked = sorted(range(len(candidates)), key=lambda i: (candidates[i][2], i))
    passed_over = []
    kept, gain = None, None
    for i in ranked:
        name, g, s = candidates[i]
        if not math.isfinite(s):
            break
        model = linear.get(name)
        diverged = (
            _at_gain(network, g, lambda: diverges_over_records(network, record, n))
            if name == "network"
            else diverges_over_records(model, record, n)
        )
        if not diverged:
            kept, gain = name, g
            break
        passed_over.append(name if g is None else f"network at gain {g:g}")
    if kept is None:  # nothing simulates the records: the linear model with the best held-out score
        kept = min(linear, key=lambda k: (linear_rmse[k], LINEAR.index(k)))
    fitted = run_dir / FITTED_FILE
    if kept != "network":
        whole = fit(kept, list(record.given.records), source=config.data.path)
        write_json(fitted, {"format": 1, **whole.to_json()})
    else:
        fitted.unlink(missing_ok=True)
        if gain != 1.0:  # the scaled read-out becomes the run's weights
            scale_correction(network.model, gain)
            save_model(run_dir / "model.safetensors", network.model)
    result = {
        "format": 3,
        "held_out_steps": int(sum(len(y) - init for y, _, init in stretches)),
        "init": int(n),
        "gains": list(gains),
        "network_rmse_by_gain": by_gain,
        "gain": gain if kept == "network" else None,
        "network_rmse": by_gain[gains.index(1.0)],
        "linear_rmse": linear_rmse,
        "linear_orders": {kind: dict(model.orders) for kind, model in linear.items()},
        "passed_over": passed_over,
        "kept": kept,
    }
    write_json(done, result)
    return result


def feature_alone(config: RunConfig) -> str:
    """What a run's network reads as its feature, in words: what its correction at gain 0 leaves."""
    m = config.model
    kind = f"ARX({m.rls_order}, {m.arx_order})" if m.arx_order else f"RLS-AR({m.rls_order})"
    if m.rls_cubes:
        kind = f"cubic NARX ({kind} with the cubes of its first {m.rls_cubes} output lags)"
    offset = " with an intercept" if m.rls_offset else ""
    if m.rls_fixed:
        how = "fixed at its least-squares fit on the training part"
    elif m.rls_prior != "none":
        how = "started from its least-squares fit on the training part, updated on the outputs it reads"
    else:
        how = "identified in context from the outputs it reads"
    return f"the {kind}{offset} {how}"


def training_time(run_dir: str | Path) -> str | None:
    """'N steps, about T' of the training logged in run_dir's metrics.jsonl (every part of a resumed
    run; the steps between logs at their logged rate), or None without a logged rate."""
    path = Path(run_dir) / "metrics.jsonl"
    if not path.is_file():
        return None
    seconds, last = 0.0, 0
    for line in path.read_text().splitlines():
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            continue
        rate = record.get("steps_per_s")
        if rate and record.get("step", 0) > last:
            seconds += (record["step"] - last) / rate
            last = record["step"]
    return f"{last} steps, about {duration(seconds)}" if last else None


def _linear_name(result: dict, kind: str) -> str:
    """'ARX(7, 5)' / 'N4SID(4)': a fitted linear model of the selection with its orders."""
    orders = result.get("linear_orders", {}).get(kind) or {}
    if not orders:
        return NAMES[kind]
    shown = [str(v) if kind == ARX.kind else f"{k}={v}" for k, v in orders.items()]
    return f"{NAMES[kind]}({', '.join(shown)})"


def selection_line(result: dict, feature: str | None = None, trained: str | None = None) -> str:
    """One line for the user: the held-out simulation RMSEs and what the run keeps, in plain words.

    feature: what the correction at gain 0 leaves (e.g. "the ARX(40, 40) with an intercept fixed at its
    least-squares fit on the training part"; default "its input feature"); trained: the training it took
    (e.g. "1875 steps, 1 min 02 s"). Where the best gain is 0 the network did not help: the line says the
    model is the feature alone and what training that was. Where the network is kept at a gain above 0 it
    names the gain and the held-out scores (at that gain, at 1, of the feature alone and of the fitted linear
    models). A candidate passed over because its free run over the whole record diverged is named.
    """
    linear = ", ".join(f"fitted {_linear_name(result, k)} {v:.4g}" for k, v in result["linear_rmse"].items())
    both = (
        f"held-out simulation ({result['held_out_steps']} steps after {result['init']} measured): "
        f"network RMSE {result['network_rmse']:.4g}, {linear}"
    )
    if result.get("passed_over"):
        diverged = ", ".join(result["passed_over"])
        both += f"; passed over as its free run over the whole record diverged: {diverged}"
    spent = f" ({trained} of training)" if trained else ""
    if result["kept"] == "network":
        gain = result.get("gain", 1.0)
        if gain == 1.0:
            return f"{both}: the run keeps the network as trained{spent}"
        by_gain = dict(zip(result["gains"], result["network_rmse_by_gain"], strict=True))
        if gain == 0:
            alone = feature or "its input feature"
            return (
                f"{both}: the network's correction did not help: the run's model is its feature alone, "
                f"{alone} (correction at gain 0, RMSE {by_gain[0.0]:.4g}); the training{spent} did not "
                "improve on it"
            )
        return (
            f"{both}: the run keeps the network with its correction at gain {gain:g} "
            f"(RMSE {by_gain[gain]:.4g}; as trained, gain 1: {by_gain[1.0]:.4g}; its feature alone, gain 0: "
            f"{by_gain[0.0]:.4g}){spent}"
        )
    kind = result["kept"]
    return (
        f"{both}: the network does not beat the linear models, so the run keeps the fitted "
        f"{_linear_name(result, kind)} (fitted.json, as `mop fit {kind}` writes it): `mop predict` and "
        f"mop.load use it; the training{spent} did not improve on it"
    )
