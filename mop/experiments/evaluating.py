"""Evaluating one test condition: the one function both `mop reproduce` and `mop pretrained build` call.

    result = evaluate_condition(exp, condition, predictors, trained, preset="small", seed=0)
    result.errors["kalman"]          # (N, T+1) per-system errors ||yhat_t - y_t||, t = 0..T
    result.summary["to_best"]        # MOP / the best predictor, MSE over t in [20, T] with its CI

The test data are the condition's: its recorded file (`data`) or N seeded test systems of the trained
family with the condition's system overrides, with outputs removed as its `missing` says.

"Best" has one definition (Experiment.best_predictor): the experiment's `best` (the exact optimum where
one exists, else the best filter that knows the system), else its reference; never the lowest error
measured, so the predictor MOP is compared with does not change with the test draw.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from mop.config import RunConfig, SystemConfig, apply_settings
from mop.errors import MopError
from mop.evaluate import evaluate, summarize
from mop.experiments import TEST_SEED_OFFSET, get_preset
from mop.experiments.results import ConditionResult
from mop.experiments.spec import Condition, Experiment
from mop.io import read_trajectories
from mop.metrics import mse_ratio_ci
from mop.missing import drop_mask, drop_outputs
from mop.predictors import PREDICTORS, is_learned
from mop.systems import generator, make_family
from mop.systems.base import Trajectories

LATE_WINDOW = (20, None)  # t in [20, T]: where the paper compares MOP with the optimal filter
MISSING_SEED_OFFSET = 9_000_011  # the test drop-out masks: generator seed + this


def test_system(trained: RunConfig, condition: Condition) -> SystemConfig:
    """The condition's test family: the trained family's config with the condition's overrides."""
    return apply_settings(trained.system, condition.system)


def test_trajectories(system: SystemConfig, num_systems: int, horizon: int, seed: int) -> Trajectories:
    """Seeded test systems (float64), apart from the training (seed) and validation streams."""
    family = make_family(system, dtype=torch.float64)
    return family.generate(num_systems, horizon, generator=generator(seed + TEST_SEED_OFFSET))


def recorded_trajectories(path: str, horizon: int) -> Trajectories:
    """The recordings of `path` with at least horizon + 1 outputs, cut to y_0..y_horizon (float64)."""
    _, data = read_trajectories(path)
    long = [(y, u) for y, u in data if len(y) > horizon]
    if not long:
        raise MopError(f"{path}: no trajectory has {horizon + 1} steps; lower the condition's horizon")
    y = torch.tensor(np.stack([y[: horizon + 1] for y, _ in long]), dtype=torch.float64)
    u = None if long[0][1] is None else np.stack([u[: horizon + 1] for _, u in long])
    return Trajectories(y=y, u=None if u is None else torch.tensor(u, dtype=torch.float64))


def with_missing(traj: Trajectories, missing: dict[str, float], seed: int) -> Trajectories:
    """traj with outputs removed (NaN) as the condition's `missing` says; y_0 always kept; seeded."""
    g = torch.Generator(device=traj.y.device).manual_seed(seed + MISSING_SEED_OFFSET)
    drop = drop_mask(
        tuple(traj.y.shape),
        missing.get("rate", 0.0),
        g,
        missing.get("burst_rate", 0.0),
        int(missing.get("burst_length", 5)),
    )
    return dataclasses.replace(traj, y=drop_outputs(traj.y, drop))


def condition_trajectories(condition: Condition, trained: RunConfig, preset: str, seed: int) -> Trajectories:
    """The condition's test data, y (N, T+1, m) with T its horizon (else the trained one): its recorded
    file, else the preset's N test systems (test seed seed + TEST_SEED_OFFSET), then its `missing`."""
    horizon = condition.horizon or trained.train.horizon  # with the command line's overrides, like the run
    if condition.data:
        traj = recorded_trajectories(condition.data, horizon)
    else:
        num_systems = get_preset(preset).num_test_systems
        traj = test_trajectories(test_system(trained, condition), num_systems, horizon, seed)
    if condition.missing:
        traj = with_missing(traj, condition.missing, seed)
    return traj


def evaluate_condition(
    exp: Experiment,
    condition: Condition,
    predictors: list,
    trained: RunConfig,
    *,
    preset: str,
    seed: int,
    progress: bool = True,
) -> ConditionResult:
    """Every predictor on the condition's test data (condition_trajectories; `trained` is the RunConfig of
    the condition's training: its family and horizon): per-system errors, eval.json's summary with the
    ratios to the experiment's reference, and "to_best", MOP's distance to exp.best_predictor.

    seed: the test seed (systems, drop-outs, bootstrap). The experiment's analyses are not run here.
    """
    traj = condition_trajectories(condition, trained, preset, seed)
    raw = evaluate(predictors, traj, progress)
    errors = {name: r["e"] for name, r in raw.items()}
    summary = summarize(raw, reference=exp.reference, seed=seed)
    summary["to_best"] = distance_to_best(errors, exp.best_predictor, seed)
    return ConditionResult(condition, traj, errors, summary)


def distance_to_best(errors: dict[str, np.ndarray], best: str, seed: int, model: str = "") -> dict | None:
    """MOP's MSE ratio to the best predictor over t in [20, T] with its bootstrap CI (None if either is
    missing from the condition): {"predictor", "window", "ratio", "low", "high"}.

    errors: predictor -> (N, T+1) per-system errors; model: "" = the first learned predictor."""
    model = model or next((n for n in errors if n in PREDICTORS and is_learned(n)), "")
    if model not in errors or best not in errors:
        return None
    e_mop, e_best = errors[model], errors[best]
    start, stop = LATE_WINDOW[0], e_mop.shape[1]
    if stop <= start:
        return None
    ratio, low, high = mse_ratio_ci(e_mop, e_best, start, stop, seed=seed)
    return {"predictor": best, "window": [start, stop], "ratio": ratio, "low": low, "high": high}
