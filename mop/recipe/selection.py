"""Never worse than the fitted linear model: the choice a records run makes after training.

After a records-recipe run has trained, its network with the correction at each gain of
mop.recipe.shrink.GAINS (1: as trained; 0: its in-context feature alone) and the ARX that `mop fit arx`
chooses on the same training part simulate the held-out data (held_out_stretches: the last 10% of a record
after the 50 measured steps before it, or the held-out trajectories, or --val) from the inputs alone, and
are scored by the RMSE of the simulated steps (a simulation that diverges scores inf:
mop.records.divergence_step).
selection.json in the run directory holds every score and the one kept:
- the network at the best gain where it simulates at least as well as the ARX: a gain below 1 is written
  into the run's weights;
- the ARX otherwise: the run directory also holds that ARX refitted on the whole estimation record, exactly
  what `mop fit arx FILE` writes (fitted.json), and `mop predict RUN`, `mop.load(RUN)` load it (they read a
  directory with fitted.json as a fitted model),
so a user never gets a run that simulates its held-out data worse than the linear model would have.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from mop.atomic import write_json
from mop.checkpoint import save_model
from mop.config import RunConfig
from mop.identify.select import fit
from mop.identify.store import FILE as FITTED_FILE
from mop.recipe.shrink import GAINS, best_gain, gain_scores, scale_correction
from mop.records import divergence_step, simulate_all
from mop.runs import load_predictor
from mop.train.estimate import duration
from mop.train.records import RecordedData

SELECTION_FILE = "selection.json"
INIT_WINDOW = 50  # measured outputs a held-out simulation starts from (the benchmarks' usual n)


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


def held_out_stretches(record: RecordedData) -> list[tuple[np.ndarray, np.ndarray, int]]:
    """(y, u, init) of each held-out stretch: where one record is split in time, its held-out tail after the
    INIT_WINDOW measured steps before it (as a test record is simulated after its initialisation window), so
    every held-out step is scored; held-out records (--val, or whole trajectories) from their own first
    min(INIT_WINDOW, L/2) outputs."""
    m = record.output_dim
    pairs = lambda a: (a[:, :m], a[:, m:])  # noqa: E731
    if record.split == "time":
        stretches = []
        for train, val in zip(record.train_parts, record.val_parts, strict=True):
            init = min(INIT_WINDOW, len(train))
            stretches.append((*pairs(np.concatenate([train[len(train) - init :], val])), init))
        return stretches
    init = max(1, min(INIT_WINDOW, min(len(a) for a in record.val_parts) // 2))
    return [(*pairs(a), init) for a in record.val_parts]


def _gains_apply(predictor) -> bool:
    """Whether the network's correction can be scaled (mop.recipe.shrink): a transformer with the mean
    read-out reading a feature, whose gain 0 is that feature alone."""
    cfg = getattr(getattr(predictor, "model", None), "cfg", None)
    return cfg is not None and getattr(cfg, "rls_order", 0) > 0 and getattr(cfg, "readout", "") == "mean"


def select_against_arx(run_dir: str | Path, config: RunConfig, record: RecordedData) -> dict:
    """Choose what the finished run in `run_dir` predicts with, by free-run simulation of its held-out data
    (held_out_stretches): the network with its correction at each gain of mop.recipe.shrink.GAINS (1: as
    trained; 0: its in-context feature alone), or `mop fit arx`'s ARX fitted on the training part. On
    a tie the network at the larger gain is kept. Writes SELECTION_FILE; a gain below 1 is written into
    the run's model.safetensors, and where the ARX wins the run also holds it refitted on the whole record
    (fitted.json, as `mop fit arx` writes it). A run that already holds SELECTION_FILE keeps its choice.
    record: config.data's records in memory, split as it asks (mop.train.records.RecordedData)."""
    run_dir = Path(run_dir)
    done = run_dir / SELECTION_FILE
    if done.is_file():
        previous = json.loads(done.read_text())
        if previous.get("format") == 2:
            return previous
    m = record.output_dim
    train = [(a[:, :m], a[:, m:]) for a in record.train_parts]
    stretches = held_out_stretches(record)
    arx = fit("arx", train, source=config.data.path)
    network = load_predictor(run_dir)
    score = lambda: stretches_rmse(network, stretches)  # noqa: E731
    gains = GAINS if _gains_apply(network) else (1.0,)
    by_gain = gain_scores(network.model, score) if len(gains) > 1 else [score()]
    gain = best_gain(by_gain) if len(gains) > 1 else 1.0
    best_rmse = by_gain[gains.index(gain)]
    arx_rmse = stretches_rmse(arx, stretches)
    kept = "network" if best_rmse <= arx_rmse and math.isfinite(best_rmse) else "arx"
    fitted = run_dir / FITTED_FILE
    if kept == "arx":
        whole = fit("arx", list(record.given.records), source=config.data.path)
        write_json(fitted, {"format": 1, **whole.to_json()})
    else:
        fitted.unlink(missing_ok=True)
        if gain != 1.0:  # the scaled read-out becomes the run's weights
            scale_correction(network.model, gain)
            save_model(run_dir / "model.safetensors", network.model)
    result = {
        "format": 2,
        "held_out_steps": int(sum(len(y) - init for y, _, init in stretches)),
        "init": int(stretches[0][2]),
        "gains": list(gains),
        "network_rmse_by_gain": by_gain,
        "gain": gain if kept == "network" else None,
        "network_rmse": by_gain[gains.index(1.0)],
        "arx_rmse": arx_rmse,
        "arx_orders": dict(arx.orders),
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


def selection_line(result: dict, feature: str | None = None, trained: str | None = None) -> str:
    """One line for the user: the held-out simulation RMSEs and what the run keeps, in plain words.

    feature: what the correction at gain 0 leaves (e.g. "the ARX(40, 40) with an intercept fixed at its
    least-squares fit on the training part"; default "its input feature"); trained: the training it took
    (e.g. "1875 steps, 1 min 02 s"). Where the best gain is 0 the network did not help: the line says the
    model is the feature alone and what training that was. Where the network is kept at a gain above 0 it
    names the gain and the held-out scores (at that gain, at 1, of the feature alone and of the fitted ARX).
    """
    both = (
        f"held-out simulation ({result['held_out_steps']} steps after {result['init']} measured): "
        f"network RMSE {result['network_rmse']:.4g}, fitted ARX {result['arx_rmse']:.4g}"
    )
    spent = f" ({trained} of training)" if trained else ""
    orders = result.get("arx_orders") or {}
    arx = f"ARX({orders['p']}, {orders.get('q', 0)})" if "p" in orders else "ARX"
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
    return (
        f"{both}: the network does not beat the ARX, so the run keeps the fitted {arx} (fitted.json, as "
        "`mop fit arx` "
        f"writes it): `mop predict` and mop.load use it; the training{spent} did not improve on it"
    )
