"""Loading a trained run directory (written by mop.train): its config, its model, its predictor.

    config.json        RunConfig (model.input_dim / output_dim resolved) -> the model's architecture; for a
                       run on recorded data also data.y_mean/y_std/u_mean/u_std -> the predictor's scaling
    model.safetensors  the weights

A run is named by its directory or by `pretrained:NAME`, a run shipped inside the package (mop.pretrained),
whose files are checked against its card's SHA-256 digests before anything is read.
Imports neither the trainer nor TensorBoard, so `mop.load` and `mop predict` start fast.
"""

from __future__ import annotations

import dataclasses
import json
import os
import warnings
from pathlib import Path
from typing import Any

import torch
from torch import nn

from mop.checkpoint import load_model_weights
from mop.config import ModelConfig, RunConfig, from_dict
from mop.errors import MopError, MopWarning
from mop.identify.store import load as load_fitted
from mop.models import build_model, predictor_names, skip_presets
from mop.models.feature_input import FEATURE_DIR, INIT_KEY, FeatureInputPredictor
from mop.models.predictor import LearnedPredictor, Normalization
from mop.plugins import PLUGINS_FILE, import_plugin
from mop.predictors import PREDICTORS, Predictor
from mop.pretrained import resolve_run_dir
from mop.systems import FAMILIES

SELECTION_FILE = "selection.json"  # a records run's held-out choice (mop.recipe.selection)


def retrain_hint(run_dir: str | os.PathLike) -> str:
    """What to do about a damaged run: the command that trains it again in place."""
    return f"retrain it with `mop train {run_dir}/config.json --out {run_dir} --fresh`"


def read_run_json(path: Path, what: str = "run file") -> Any:
    """JSON of a run file; binary garbage or broken JSON is a one-line MopError naming the file."""
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        why = f"{err.msg} at line {err.lineno}" if isinstance(err, json.JSONDecodeError) else "not text"
        raise MopError(
            f"{path} is damaged (not valid JSON: {why}); delete the run directory {path.parent} and "
            f"train it again"
        ) from None


def load_config(run_dir: str | os.PathLike) -> RunConfig:
    """The RunConfig saved in `run_dir`/config.json; MopError for a missing or damaged run directory."""
    run_dir = resolve_run_dir(run_dir)
    if not run_dir.is_dir():
        raise MopError(f"run directory {run_dir} does not exist; train one with `mop train --out {run_dir}`")
    path = run_dir / "config.json"
    if not path.is_file():
        raise MopError(f"{run_dir} has no config.json; it is not a mop run directory")
    import_run_plugins(run_dir)
    data = read_run_json(path)
    system = data.get("system") if isinstance(data, dict) else None
    family = system.get("family") if isinstance(system, dict) else None
    if isinstance(family, str) and family not in FAMILIES:
        raise MopError(
            f"{run_dir} was trained on the system family {family!r}, which is not registered here (a "
            f"plugin's family, in a run without {PLUGINS_FILE}): import its file first "
            "(mop.plugins.import_plugin), or train the run again with this version, which records it"
        )
    try:
        return from_dict(RunConfig, data)
    except MopError as err:
        raise MopError(
            f"{path} is damaged ({err}); delete the run directory {run_dir} and train it again"
        ) from None


def import_run_plugins(run_dir: Path) -> None:
    """Import the plugin files a run directory's PLUGINS_FILE lists (mop.plugins), one-line MopError for one
    that is gone."""
    listed = run_dir / PLUGINS_FILE
    if not listed.is_file():
        return
    for name in read_run_json(listed):
        plugin = Path(name)
        if not plugin.is_file():
            raise MopError(
                f"{run_dir} was trained on a family from the plugin {plugin}, which is not there any more; "
                f"put the file back (or edit {listed} to where it is now)"
            )
        import_plugin(plugin)


def load_model(
    run_dir: str | os.PathLike, device: str | torch.device = "cpu"
) -> tuple[nn.Module, ModelConfig]:
    """The model of a run directory (config.json + model.safetensors), in eval mode on `device`."""
    run_dir = resolve_run_dir(run_dir)
    config = load_config(run_dir)
    model = build_model(config.model)
    load_model_weights(Path(run_dir) / "model.safetensors", model, retrain=retrain_hint(run_dir))
    return model.to(device).eval(), config.model


def load_predictor(
    run_dir: str | os.PathLike, device: str | torch.device = "cpu", mode: str = "window"
) -> LearnedPredictor | FeatureInputPredictor:
    """A trained run as a LearnedPredictor (the Predictor interface of the classical filters); a run whose
    network reads its feature's run (data.feature_input = "free-run") as a FeatureInputPredictor around
    it, which reads the records' own channels.

    A run on recorded data predicts in the data's units (its normalisation, from config.json, is applied).
    `run_dir` may be `pretrained:NAME` (checked once, then read from the package).
    """
    source = str(run_dir)
    run_dir = resolve_run_dir(run_dir)
    model, config = load_model(run_dir, device)
    warn_if_unfinished(Path(run_dir), load_config(run_dir))
    name = predictor_names().get(config.arch, config.arch)  # the predictor its architecture registered
    norm, stats = load_normalization(run_dir), load_input_stats(run_dir)
    predictor = LearnedPredictor(
        model, name=name, mode=mode, normalization=norm, input_stats=stats, source=source
    )
    data = load_config(run_dir).data
    if data is not None and data.reads_feature_run:  # its feature's run is an input
        if not (Path(run_dir) / FEATURE_DIR).is_dir():
            raise MopError(
                f"{source} holds no {FEATURE_DIR}/, the least-squares model its network reads "
                "(data.feature_input=free-run); train the run again with the same command"
            )
        feature = load_fitted(Path(run_dir) / FEATURE_DIR)
        predictor = FeatureInputPredictor(predictor, feature, int(feature.info[INIT_KEY]))
    reading = chosen_reading(Path(run_dir))
    if reading is not None:
        with_reading(predictor, reading)
    return predictor


def with_reading(predictor: LearnedPredictor, reading: str) -> None:
    """Set a learned predictor's forecast_mode (in place: its config and its model's), the reading a
    records run's held-out check scores or chose."""
    cfg = dataclasses.replace(predictor.model.cfg, forecast_mode=reading)
    predictor.model.cfg = predictor.cfg = cfg


def chosen_reading(run_dir: Path) -> str | None:
    """The forecast_mode a records run's held-out check chose (SELECTION_FILE's "reading",
    mop.recipe.selection), or None where it chose none."""
    path = run_dir / SELECTION_FILE
    return json.loads(path.read_text()).get("reading") if path.is_file() else None


def warn_if_unfinished(run_dir: Path, config: RunConfig) -> None:
    """A MopWarning where the run stopped before its last step (no done.json): its predictions come from the
    weights of its last checkpoint, which `mop train` with the same arguments resumes."""
    if (run_dir / "done.json").exists() or not (run_dir / "metrics.jsonl").exists():
        return
    steps = [
        json.loads(line).get("step", 0)
        for line in (run_dir / "metrics.jsonl").read_text().splitlines()
        if line
    ]
    reached = max(steps, default=0)
    warnings.warn(
        MopWarning(
            f"{run_dir} is unfinished: trained to step {reached} of {config.train.steps}; these predictions "
            "come from its last checkpoint's weights (run the same mop train command to finish it)"
        ),
        stacklevel=2,
    )


def load_input_stats(run_dir: str | os.PathLike) -> tuple[list[float], list[float]] | None:
    """(mean, std) per model-input channel from inputs.json (None for runs trained before it existed)."""
    path = Path(run_dir) / "inputs.json"
    if not path.is_file():
        return None
    stats = read_run_json(path)
    if not (isinstance(stats, dict) and all(isinstance(stats.get(k), list) for k in ("mean", "std"))):
        raise MopError(f"{path} is damaged (no mean and std lists); {retrain_hint(run_dir)}")
    return stats["mean"], stats["std"]


def load_normalization(run_dir: str | os.PathLike) -> Normalization | None:
    """The per-channel scaling of a run on recorded data (config.json's data), None for simulated runs."""
    data = load_config(run_dir).data
    if data is None:
        return None
    if not data.fitted:
        raise MopError(f"{run_dir}/config.json has data without its fitted normalisation; retrain the run")
    return Normalization.from_lists(data.y_mean, data.y_std, data.u_mean, data.u_std)


def register_learned(name: str, arch: str, skip_presets: tuple[str, ...] = ()) -> None:
    """Register predictor `name`: a trained run of model architecture `arch` (mop.models), loaded from the
    run directory given as make_predictor(name, run_dir=...); mode "window", "sliding" (the paper's) or
    "stream" (mop.models.predict).
    make_predictor(name, run_dir=..., model=m) wraps the trained model `m` handed over by the trainer
    instead of loading the weights again (the run's config.json still gives a data run's scaling).
    skip_presets: presets under which experiments train it only when asked."""

    def load(
        run_dir: str, mode: str = "window", device: str = "cpu", model: nn.Module | None = None
    ) -> Predictor:
        if model is None:
            return load_predictor(run_dir, device=device, mode=mode)
        model = model.to(device).eval()
        return LearnedPredictor(model, name=name, mode=mode, normalization=load_normalization(run_dir))

    PREDICTORS.add(name, load, learned=True, arch=arch, gaussian=True, skip_presets=tuple(skip_presets))


for _arch, _name in sorted(predictor_names().items()):  # the built-in architectures' predictors (mop, gru)
    register_learned(_name, _arch, skip_presets(_arch))
