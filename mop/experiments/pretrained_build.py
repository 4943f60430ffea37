"""`mop pretrained build [NAME ...]`: train, measure and ship the catalog's models (mop.pretrained.catalog).

For each model: train the RunConfig its experiment condition gets under its preset (the recipe as it is in
mop.experiments.presets at build time) into a work directory (a finished run there is reused, so a rebuild
that changes only the card does not retrain), evaluate it on N fresh test systems (the preset's N, the
test seed of `mop reproduce`) beside the condition's predictors, and write the shipped directory
(config.json, model.safetensors, card.json with the measured numbers and SHA-256 digests, CARD.md rendered
from card.json) atomically: a failed build leaves the shipped model as it was.

Deterministic for a seed on the same torch build and thread count (training is seeded; CPU kernels are
deterministic for a fixed thread count).
"""

from __future__ import annotations

import dataclasses
import json
import os
import platform
import shutil
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mop.atomic import write_json, write_text
from mop.config import RunConfig
from mop.errors import MopError
from mop.evaluate import evaluate, windows
from mop.experiments import TEST_SEED_OFFSET, get_experiment, get_preset, run_config
from mop.experiments.analyses import SIMULATION, horizon_errors, simulation_analysis
from mop.experiments.evaluating import evaluate_condition, test_system, test_trajectories
from mop.experiments.planning import classical_predictor, config_hash
from mop.experiments.results import ConditionResult
from mop.experiments.spec import Condition
from mop.experiments.validate import evaluated
from mop.metrics import mse_ratio_ci
from mop.predictors import forecast, is_learned
from mop.pretrained import PREFIX, ROOT, file_digests
from mop.pretrained.card import render_card
from mop.pretrained.catalog import CATALOG, ShippedModel, catalog_entry
from mop.runs import load_config, load_predictor
from mop.train import train

FORECAST_STEPS = 10
FORECAST_START = 20
NOISE_FACTORS = (0.1, 1.0, 5.0, 10.0)  # the card's noise-shift table: test variance / trained variance
NOISE_SHIFT_SYSTEMS = 200


def condition_of(entry: ShippedModel) -> Condition:
    exp = get_experiment(entry.experiment)
    conditions = exp.conditions_for(entry.preset)
    if not entry.condition:
        return conditions[0]
    for condition in conditions:
        if condition.name == entry.condition:
            return condition
    raise MopError(f"experiment {entry.experiment} has no condition {entry.condition!r}")


def training_config(entry: ShippedModel, overrides: list[str] = ()) -> RunConfig:
    """The RunConfig the shipped model is trained with (preset < experiment < condition < overrides)."""
    exp = get_experiment(entry.experiment)
    return run_config(exp, entry.preset, entry.seed, "gpt", condition_of(entry), list(overrides))


def machine() -> dict[str, Any]:
    """The machine a build ran on: CPU, cores, torch build and its thread count."""
    return {
        "cpu": _cpu_name(),
        "cores": os.cpu_count(),
        "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        "python": platform.python_version(),
        "platform": platform.platform(terse=True),
    }


def _cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def train_entry(entry: ShippedModel, work: Path, overrides: list[str] = (), progress: bool = True) -> Path:
    """Train (or reuse) the entry's run in work/<name>-<config hash>; build.json records its wall time."""
    config = training_config(entry, overrides)
    run_dir = work / f"{entry.name}-{config_hash(config)}"
    record = run_dir / "build.json"
    if (run_dir / "done.json").exists():
        if not record.exists():  # finished elsewhere: its training time is unknown
            write_json(record, {"train_seconds": None, "machine": None})
        return run_dir
    resumed = (run_dir / "checkpoint.safetensors").exists()
    start = time.perf_counter()
    train(config, run_dir, progress=progress)
    seconds = None if resumed else time.perf_counter() - start  # a resumed run's total time is unknown
    write_json(record, {"train_seconds": seconds, "machine": machine()})
    return run_dir


def _late(horizon: int) -> str:
    return f"[20,{horizon + 1})"


def _ratios(e_num: np.ndarray, e_den: np.ndarray, seed: int) -> dict[str, dict[str, float]]:
    """{window: {"ratio", "low", "high"}} of MSE(e_num) / MSE(e_den), e (N, T+1), paired bootstrap CIs."""
    horizon = e_num.shape[1] - 1
    return {
        w: dict(zip(("ratio", "low", "high"), mse_ratio_ci(e_num, e_den, *span, seed=seed), strict=True))
        for w, span in windows(horizon).items()
        if span[0] < span[1] <= horizon + 1
    }


def measure(entry: ShippedModel, run_dir: Path, progress: bool = True) -> dict[str, Any]:
    """The card's measured sections (evaluation, forecast, simulation, noise_shift) of the model in run_dir.
    An experiment with the "simulation" analysis (a class model) gets the free-run simulation table of
    mop.experiments.analyses (one-step and simulation RMSE after the condition's context, every predictor)
    and, unless it also lists "forecast", no k-step forecast table.

    The condition is evaluated by the runner's own function (mop.experiments.evaluating.evaluate_condition:
    the same test data, `missing` and `data` included, the same test seed and predictor options as
    `mop reproduce EXPERIMENT --preset PRESET`), so the card's numbers are that report's; "best" is the
    experiment's best_predictor, as in the report.
    """
    exp, condition = get_experiment(entry.experiment), condition_of(entry)
    config = load_config(run_dir)
    model = load_predictor(run_dir)
    listed = evaluated(exp, entry.preset, condition)
    # the experiment's learned slot names the model whatever its architecture (as its report does)
    model.name = next(n for n in listed if is_learned(n))
    names = [n for n in listed if not is_learned(n)]
    best, reference = exp.best_predictor, exp.reference
    if best not in names:
        raise MopError(f"experiment {exp.name}: its best predictor {best} is not evaluated; list it")
    system = test_system(config, condition)
    predictors = [model, *(classical_predictor(n, entry.preset, entry.seed, system) for n in names)]
    result = evaluate_condition(
        exp, condition, predictors, config, preset=entry.preset, seed=entry.seed, progress=progress
    )
    shown = [p for p in predictors if p.name in (model.name, reference, best)]
    ref = next(p for p in predictors if p.name == reference)
    horizon = result.traj.y.shape[1] - 1
    simulates = SIMULATION in exp.analyses  # a class model: scored in free-run simulation
    return {
        "evaluation": _evaluation(result, model.name, reference, best, entry.seed),
        "forecast": None if simulates and "forecast" not in exp.analyses else _forecast(result.traj, shown),
        SIMULATION: simulation_analysis(result, predictors, reference)[SIMULATION] if simulates else None,
        "noise_shift": noise_shift(model, ref, system, horizon, entry.seed),
    }


def _evaluation(result: ConditionResult, model: str, reference: str, best: str, seed: int) -> dict[str, Any]:
    """The card's evaluation: errors per window, MOP's MSE ratios to the reference and the best."""
    summary = result.summary
    return {
        "num_systems": int(result.traj.y.shape[0]),
        "test_seed": seed + TEST_SEED_OFFSET,
        "horizon": result.traj.y.shape[1] - 1,
        "reference": reference,
        "best": best,
        "errors": {n: p["window_error"] for n, p in summary["predictors"].items()},
        "ratio_to_reference": summary["ratios_to_reference"]["ratios"][model],
        "ratio_to_best": _ratios(result.errors[model], result.errors[best], seed),
    }


def _forecast(traj, shown: list) -> dict[str, Any]:
    """The card's forecast table: mean error k = 1..FORECAST_STEPS steps ahead from t >= FORECAST_START."""
    table = {
        p.name: horizon_errors(traj.y, forecast(p, traj, FORECAST_STEPS), FORECAST_START)
        for p in shown
        if callable(getattr(p, "forecast", None))
    }
    return {"k": list(range(1, FORECAST_STEPS + 1)), "start": FORECAST_START, "error": table}


def noise_shift(model, reference, system, horizon: int, seed: int) -> dict[str, Any] | None:
    """MOP/reference MSE ratio over t >= 20 at test noise variances NOISE_FACTORS x the trained ones, on
    NOISE_SHIFT_SYSTEMS test systems; None for a family without noise_var_w / noise_var_v."""
    if not all(hasattr(system, k) for k in ("noise_var_w", "noise_var_v")):
        return None
    rows = []
    for factor in NOISE_FACTORS:
        w, v = system.noise_var_w * factor, system.noise_var_v * factor
        shifted = dataclasses.replace(system, noise_var_w=w, noise_var_v=v)
        traj = test_trajectories(shifted, NOISE_SHIFT_SYSTEMS, horizon, seed)
        raw = evaluate([model, reference], traj, progress=False)
        span = windows(horizon)[_late(horizon)]
        ratio = mse_ratio_ci(raw[model.name]["e"], raw[reference.name]["e"], *span, seed=seed)
        ci = dict(zip(("ratio", "low", "high"), ratio, strict=True))
        rows.append({"factor": factor, "noise_var_w": w, "noise_var_v": v, **ci})
    trained = {"noise_var_w": system.noise_var_w, "noise_var_v": system.noise_var_v}
    return {"trained": trained, "num_systems": NOISE_SHIFT_SYSTEMS, "rows": rows}


def rebuild_command(entry: ShippedModel, threads: int, overrides: list[str]) -> str:
    """The command that rebuilds `entry` as built (the catalog's preset unless another was given)."""
    preset = f" --preset {entry.preset}" if entry.preset != catalog_entry(entry.name).preset else ""
    return " ".join([f"mop pretrained build {entry.name} --threads {threads}{preset}", *overrides])


def make_card(
    entry: ShippedModel, run_dir: Path, measured: dict[str, Any], command: str, digests: dict[str, str]
) -> dict[str, Any]:
    """card.json: the entry, the run's config and training record, the measured numbers, the digests."""
    config = json.loads((run_dir / "config.json").read_text())
    record = json.loads((run_dir / "build.json").read_text())
    weights = load_predictor(run_dir).model
    return {
        "name": entry.name,
        "summary": entry.summary,
        "not_for": entry.not_for,
        "family": config["system"],
        "model": config["model"],
        "num_parameters": sum(p.numel() for p in weights.parameters()),
        "size_bytes": (run_dir / "model.safetensors").stat().st_size,
        "recipe": {
            "preset": entry.preset,
            "experiment": entry.experiment,
            "condition": entry.condition,
            "train": config["train"],
        },
        "seed": config["train"]["seed"],
        "steps": config["train"]["steps"],
        "train_seconds": record["train_seconds"],
        "machine": record["machine"],
        **measured,
        "rebuild": command,
        "sha256": digests,
    }


def ship(entry: ShippedModel, run_dir: Path, card_fields: dict[str, Any], out_root: Path) -> Path:
    """Write out_root/<name>/ (config.json, model.safetensors, card.json, CARD.md) in one rename."""
    out_root.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=out_root, prefix=f".{entry.name}-"))
    try:
        for name in ("config.json", "model.safetensors"):
            shutil.copyfile(run_dir / name, tmp / name)
        card = make_card(entry, run_dir, card_fields, card_fields.pop("rebuild"), file_digests(tmp))
        write_json(tmp / "card.json", card)
        write_text(tmp / "CARD.md", render_card(card))
        dest = out_root / entry.name
        old = out_root / f".{entry.name}-old"
        if dest.exists():
            shutil.rmtree(old, ignore_errors=True)
            dest.rename(old)
        for path in (tmp, *tmp.iterdir()):  # package data: readable by all, as pip installs it
            path.chmod(0o755 if path.is_dir() else 0o644)
        tmp.rename(dest)
        shutil.rmtree(old, ignore_errors=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return dest


def build(
    names: list[str] | None = None,
    *,
    work: Path = Path("runs/pretrained-build"),
    out_root: Path = ROOT,
    threads: int = 2,
    overrides: list[str] = (),
    preset: str | None = None,
    progress: bool = True,
    report: Callable[[str], None] = print,
) -> list[Path]:
    """Train (or reuse), measure and ship the named catalog models (all when names is empty).

    preset: train and measure under this preset instead of each entry's (e.g. "smoke" in tests).
    report: gets the line naming each shipped model as it is written.
    """
    entries = [catalog_entry(n) for n in names] if names else list(CATALOG)
    if preset is not None:
        get_preset(preset)
        entries = [dataclasses.replace(e, preset=preset) for e in entries]
    for entry in entries:  # bad names or overrides fail here, before any training
        training_config(entry, overrides)
    torch.set_num_threads(threads)
    shipped = []
    for entry in entries:
        run_dir = train_entry(entry, work, overrides, progress)
        measured = measure(entry, run_dir, progress)
        measured["rebuild"] = rebuild_command(entry, threads, list(overrides))
        shipped.append(ship(entry, run_dir, measured, out_root))
        report(f"built {PREFIX}{entry.name} -> {shipped[-1]}")
    return shipped
