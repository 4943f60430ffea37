"""Loading a trained run directory (written by mop.train): its config, its model, its predictor.

    config.json        RunConfig (model.input_dim / output_dim resolved) -> the model's architecture; for a
                       run on recorded data also data.y_mean/y_std/u_mean/u_std -> the predictor's scaling
    model.safetensors  the weights

Imports neither the trainer nor TensorBoard, so `mop.load` and `mop predict` start fast.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import torch
from torch import nn

from mop.checkpoint import load_model_weights
from mop.config import ModelConfig, RunConfig, from_dict
from mop.errors import MopError
from mop.models import build_model, predictor_names, skip_presets
from mop.models.predictor import LearnedPredictor, Normalization
from mop.predictors import PREDICTORS, Predictor


def load_config(run_dir: str | os.PathLike) -> RunConfig:
    """The RunConfig saved in `run_dir`/config.json; MopError for a missing or damaged run directory."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise MopError(f"run directory {run_dir} does not exist; train one with `mop train --out {run_dir}`")
    path = run_dir / "config.json"
    if not path.is_file():
        raise MopError(f"{run_dir} has no config.json; it is not a mop run directory")
    try:
        return from_dict(RunConfig, json.loads(path.read_text()))
    except json.JSONDecodeError:
        raise MopError(f"{path} is not valid JSON; the run directory is damaged") from None


def load_model(
    run_dir: str | os.PathLike, device: str | torch.device = "cpu"
) -> tuple[nn.Module, ModelConfig]:
    """The model of a run directory (config.json + model.safetensors), in eval mode on `device`."""
    config = load_config(run_dir)
    model = build_model(config.model)
    load_model_weights(Path(run_dir) / "model.safetensors", model)
    return model.to(device).eval(), config.model


def load_predictor(
    run_dir: str | os.PathLike, device: str | torch.device = "cpu", mode: str = "window"
) -> LearnedPredictor:
    """A trained run as a LearnedPredictor (the Predictor interface of the classical filters).

    A run on recorded data predicts in the data's units (its normalisation, from config.json, is applied).
    """
    model, config = load_model(run_dir, device)
    name = predictor_names().get(config.arch, config.arch)  # the predictor its architecture registered
    return LearnedPredictor(model, name=name, mode=mode, normalization=load_normalization(run_dir))


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
    run directory given as make_predictor(name, run_dir=...); mode "window" (the paper's) or "stream".
    skip_presets: presets under which experiments train it only when asked."""

    def load(run_dir: str, mode: str = "window", device: str = "cpu") -> Predictor:
        return load_predictor(run_dir, device=device, mode=mode)

    PREDICTORS.add(name, load, learned=True, arch=arch, gaussian=True, skip_presets=tuple(skip_presets))


for _arch, _name in sorted(predictor_names().items()):  # the built-in architectures' predictors (mop, gru)
    register_learned(_name, _arch, skip_presets(_arch))
