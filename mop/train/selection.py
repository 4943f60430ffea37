"""Never worse than the fitted linear model: a records run against the ARX `mop fit arx` gives.

After a records-recipe run has trained, its network and the ARX that `mop fit arx` chooses on the same
training part simulate the held-out part of the estimation record (data.validation_fraction: the last 10%
of one record, or the held-out trajectories, or --val), each from its first INIT_WINDOW measured outputs
and the inputs alone, and are scored by the RMSE of the rest (a simulation that diverges scores inf:
mop.records.divergence_step). selection.json in the run directory holds both scores and the one kept:
- the network where it simulates better: the run predicts as trained;
- the ARX otherwise: the run directory also holds that ARX refitted on the whole estimation record, exactly
  what `mop fit arx FILE` writes (fitted.json), and `mop predict RUN`, `mop.load(RUN)` load it (they read a
  directory with fitted.json as a fitted model), so a user never gets a run that simulates its held-out
  data worse than the linear model would have.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from mop.atomic import write_json
from mop.config import RunConfig
from mop.identify.select import fit
from mop.identify.store import FILE as FITTED_FILE
from mop.io import read_trajectories
from mop.records import divergence_step, simulate_all
from mop.runs import load_predictor
from mop.train.records import recorded_data

SELECTION_FILE = "selection.json"
INIT_WINDOW = 50  # measured outputs a held-out simulation starts from (the benchmarks' usual n)


def simulation_rmse(predictor, data: list[tuple[np.ndarray, np.ndarray]], init: int) -> float:
    """RMSE of y[init:] simulated from y[:init] and the inputs, pooled over the records; inf where the
    simulation turned non-finite (a diverged run is not scored over its finite steps)."""
    sims = simulate_all(predictor, data, init)
    if any(divergence_step(y, s) is not None for (y, _), s in zip(data, sims, strict=True)):
        return math.inf
    errors = np.concatenate([y[init:] - s for (y, _), s in zip(data, sims, strict=True)])
    return float(np.sqrt(np.nanmean(errors**2)))


def select_against_arx(run_dir: str | Path, config: RunConfig) -> dict:
    """Compare the trained run in `run_dir` with `mop fit arx`'s ARX on the held-out part; write
    SELECTION_FILE (and, where the ARX wins, the ARX refitted on the whole record as fitted.json)."""
    run_dir = Path(run_dir)
    record = recorded_data(config.data)
    m = record.output_dim
    split = lambda parts: [(a[:, :m], a[:, m:]) for a in parts]  # noqa: E731
    train, held_out = split(record.train_parts), split(record.val_parts)
    init = max(1, min(INIT_WINDOW, min(len(y) for y, _ in held_out) // 2))
    arx = fit("arx", train, source=config.data.path)
    network_rmse = simulation_rmse(load_predictor(run_dir), held_out, init)
    arx_rmse = simulation_rmse(arx, held_out, init)
    kept = "network" if network_rmse < arx_rmse else "arx"
    fitted = run_dir / FITTED_FILE
    if kept == "arx":
        whole = fit("arx", read_trajectories(config.data.path)[1], source=config.data.path)
        write_json(fitted, {"format": 1, **whole.to_json()})
    elif fitted.exists():
        fitted.unlink()
    result = {
        "held_out_steps": int(sum(len(y) - init for y, _ in held_out)),
        "init": init,
        "network_rmse": network_rmse,
        "arx_rmse": arx_rmse,
        "arx_orders": dict(arx.orders),
        "kept": kept,
    }
    write_json(run_dir / SELECTION_FILE, result)
    return result


def selection_line(result: dict) -> str:
    """One line for the user: both held-out simulation RMSEs and what the run keeps."""
    both = (
        f"held-out simulation ({result['held_out_steps']} steps after {result['init']} measured): "
        f"network RMSE {result['network_rmse']:.4g}, fitted ARX {result['arx_rmse']:.4g}"
    )
    if result["kept"] == "network":
        return f"{both}: the run keeps the network"
    return (
        f"{both}: the network does not beat the ARX, so the run keeps the ARX (fitted.json, as `mop fit arx` "
        "writes it): `mop predict` and mop.load use it"
    )
