"""The run directory of a training run (rank 0 writes it):

    config.json             RunConfig with model.input_dim/output_dim resolved (rebuilds the model, mop.runs);
                            for recorded data also data.y_mean/y_std/u_mean/u_std (the predictor's scaling)
    model.safetensors       model weights (latest checkpoint or final)
    checkpoint.safetensors  model + AdamW state + RNG states + step (mop.checkpoint), for resuming
    metrics.jsonl           {"step", "loss", "lr", "steps_per_s"} and {"step", "val_loss"} records
    tb/                     TensorBoard scalars
    inputs.json             per-channel mean and std of the model's inputs on the validation systems (what
                            the predictor's out-of-distribution warning compares new inputs with)
    done.json               written last; train() on a finished run with the same config returns at once
    .lock                   the advisory lock of the process training it (mop.train.lock)

A directory holding another config is refused, naming the first differing key. `fresh_start` removes what
a damaged run holds (weights, checkpoint, metrics, done.json) so `mop train RUN/config.json --out RUN
--fresh` trains it again in place.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import torch
from torch import Tensor, nn

from mop.atomic import write_json, write_text
from mop.checkpoint import load_checkpoint, save_checkpoint, save_model
from mop.config import DataConfig, RunConfig, to_dict
from mop.errors import MopError
from mop.models import check_arch
from mop.plugins import PLUGINS_FILE, plugin_file
from mop.runs import read_run_json, retrain_hint
from mop.systems import FAMILIES, make_family
from mop.train.auto import resolve_features
from mop.train.data import validates_tails
from mop.train.records import RecordedData, TrainingRecords, recorded_data

TRAINING_FILES = (
    "model.safetensors",
    "checkpoint.safetensors",
    "metrics.jsonl",
    "done.json",
    "inputs.json",
    "shrink.json",  # mop.recipe.shrink's gain of the correction after training
    "selection.json",  # mop.recipe.selection's choice after training, and the ARX it may keep
    "fitted.json",
)


def resolve_config(config: RunConfig, records: TrainingRecords | None = None) -> RunConfig:
    """Fill model.input_dim / output_dim (0 = from the system family or the data file): d_in = m + k
    (+ m with model.observation_mask, which training with drop-outs sets), d_out = m; for recorded data
    also the normalisation fitted on the training split (data.y_mean, ...); model.features=auto resolved
    (mop.train.auto). records: the recorded data in memory (None: read from data.path)."""
    check_arch(config.model.arch)
    config = resolve_features(config)
    if config.train.drops_outputs and not config.model.observation_mask:
        config = dataclasses.replace(config, model=dataclasses.replace(config.model, observation_mask=True))
    if config.data is not None:
        return _resolve_data(config, records)
    family = make_family(config.system)
    d_in, m = family.output_dim + family.input_dim, family.output_dim
    return _with_dims(config, d_in, m, f"the {config.system.family} family")


def _with_dims(config: RunConfig, d_in: int, m: int, source: str) -> RunConfig:
    """d_in = m + k, plus m mask channels for a model with an observation mask."""
    model = config.model
    d_in += m if model.observation_mask else 0
    for name, value in (("input_dim", d_in), ("output_dim", m)):
        if getattr(model, name) not in (0, value):
            raise MopError(
                f"model.{name}={getattr(model, name)} does not match {source} ({value}); leave it at 0"
            )
    return dataclasses.replace(config, model=dataclasses.replace(model, input_dim=d_in, output_dim=m))


def _resolve_data(config: RunConfig, records: TrainingRecords | None) -> RunConfig:
    data = recorded_data(config.data, records)
    if data.num_missing and not config.model.observation_mask:
        raise MopError(
            f"{config.data.path} has {data.num_missing} missing outputs (NaN / empty cells); train a model "
            "that reads them with model.observation_mask=true (or train.missing_rate=0.1), or fill them"
        )
    data.check_lengths(config.train.horizon, validates_tails(config, records))
    kept = config.train.init and config.data.fitted  # fine-tuning keeps the source's normalisation
    stats = {} if kept else data.fit()
    for name, value in stats.items():
        given = getattr(config.data, name)
        if given is not None and [float(v) for v in given] != value:
            raise MopError(
                f"data.{name} {given} differs from the fit on the training split of {config.data.path} "
                f"({value}); leave it out (the file or the split changed)"
            )
    config = dataclasses.replace(config, data=dataclasses.replace(config.data, **stats))
    model = config.model
    if model.rls_prior == "fit":  # the feature starts as the ARX fitted on the training part
        theta = data.fit_prior(
            config.data, model.rls_order, model.arx_order, model.rls_offset, model.rls_cubes
        )
        fill = model.rls_fill_range
        if model.record_norm == "causal" and fill is None:
            fill = training_range(data, config.data)
        model = dataclasses.replace(model, rls_prior=theta, rls_fill_range=fill)
        config = dataclasses.replace(config, model=model)
    d_in, m = data.output_dim + data.input_dim, data.output_dim
    return _with_dims(config, d_in, m, f"the data file {config.data.path}")


def training_range(data: RecordedData, cfg: DataConfig) -> list[float]:
    """model.rls_fill_range of a class model whose feature starts at the fit on the training part: each
    output's least then greatest value over the normalised training parts (the fit's units). Its feature's
    free run is held within those outputs widened by twice their span (mop.filters.rls.fill_bounds), as a
    `--context` reading's is (mop.incontext.with_context_range), not within the few outputs measured before
    a simulation: a held-out tail simulated after 50 outputs of a plant at rest would otherwise hold the
    fitted ARX within a few of their spans, so the feature alone (the correction at gain 0) would not be
    the fitted ARX the run names."""
    m = data.output_dim
    outputs = np.concatenate([a[:, :m] for a in data.normalised(cfg, data.train_parts)])
    return [*map(float, np.nanmin(outputs, 0)), *map(float, np.nanmax(outputs, 0))]


def check_run_dir(out_dir: Path, config: RunConfig) -> bool:
    """True when `out_dir` holds a finished run of `config`; MopError when it holds a different config."""
    path = out_dir / "config.json"
    if not path.exists():
        return False
    saved = read_run_json(path)
    if not isinstance(saved, dict):
        raise MopError(
            f"{path} is damaged (a {type(saved).__name__}, not a config table); delete the run directory "
            f"{out_dir} and train it again"
        )
    now = json.loads(json.dumps(to_dict(config)))  # as config.json holds it: tuples are lists there
    if saved != now:
        diff = _diff(saved, now)
        raise MopError(
            f"{out_dir} holds a run with a different config ({diff}); train into another --out, or delete "
            f"{out_dir} to train this config there"
        )
    return (out_dir / "done.json").exists()


def fresh_start(out_dir: Path) -> None:
    """Remove a run's training files (weights, checkpoint, metrics, done.json, tb/); keep config.json."""
    for name in TRAINING_FILES:
        (out_dir / name).unlink(missing_ok=True)
    shutil.rmtree(out_dir / "tb", ignore_errors=True)


def write_input_stats(out_dir: Path, inputs: Tensor) -> None:
    """inputs.json: per-channel mean and std of the model inputs (N, T, d_in) the run was validated on."""
    flat = inputs.reshape(-1, inputs.shape[-1]).double()
    stats = {"mean": flat.mean(0).tolist(), "std": flat.std(0).clamp_min(1e-12).tolist()}
    write_json(out_dir / "inputs.json", stats)


def _diff(a: dict, b: dict, prefix: str = "") -> str:
    for key in sorted(set(a) | set(b)):
        x, y = a.get(key), b.get(key)
        if isinstance(x, dict) and isinstance(y, dict):
            found = _diff(x, y, f"{prefix}{key}.")
            if found:
                return found
        elif x != y:
            return f"{prefix}{key}: saved {x!r}, now {y!r}"
    return ""


def write_config(out_dir: Path, config: RunConfig) -> None:
    """config.json, and beside it PLUGINS_FILE where the system family came from a plugin (mop.plugins), so
    that loading the run imports the plugin before reading the config."""
    out_dir.mkdir(parents=True, exist_ok=True)
    plugin = plugin_file(FAMILIES.get(config.system.family)) if config.data is None else None
    if plugin is not None:
        write_json(out_dir / PLUGINS_FILE, [str(plugin)])
    write_json(out_dir / "config.json", to_dict(config))


def write_done(out_dir: Path, step: int, kept_step: int | None = None) -> None:
    """done.json: the last step, and with train.keep_best the step whose weights model.safetensors holds."""
    kept = {} if kept_step is None else {"kept": kept_step}
    write_json(out_dir / "done.json", {"step": step, **kept})


class MetricsLog:
    """metrics.jsonl (JSON record a line) + TensorBoard scalars; resume drops records past the checkpoint."""

    def __init__(self, out_dir: Path, resume_step: int) -> None:
        from torch.utils.tensorboard import SummaryWriter

        self.path = out_dir / "metrics.jsonl"
        kept = []
        if self.path.exists():
            for line in self.path.read_text().splitlines():
                with contextlib.suppress(json.JSONDecodeError):
                    record = json.loads(line)
                    if record.get("step", 0) <= resume_step:
                        kept.append(line)
        write_text(self.path, "".join(line + "\n" for line in kept))
        self.writer = SummaryWriter(str(out_dir / "tb"), purge_step=resume_step + 1 if resume_step else None)

    def best_val(self) -> tuple[int, float] | None:
        """(step, val_loss) of the lowest validation loss logged so far (the earliest on a tie), or None."""
        best = None
        for line in self.path.read_text().splitlines():
            record = json.loads(line)
            if "val_loss" in record and (best is None or record["val_loss"] < best[1]):
                best = (record["step"], record["val_loss"])
        return best

    def log(self, record: dict) -> None:
        with open(self.path, "a") as handle:
            handle.write(json.dumps(record) + "\n")
        for key, value in record.items():
            if key != "step" and isinstance(value, float):
                tag = "val/loss" if key == "val_loss" else f"train/{key}"
                self.writer.add_scalar(tag, value, record["step"])

    def close(self) -> None:
        self.writer.close()


# ----------------------------------------------------------------------------- the whole training state


def save_training_state(
    out_dir: Path,
    step: int,
    model: nn.Module,
    optimizer: torch.optim.Optimizer,
    generator: torch.Generator,
    device: torch.device,
    with_model: bool = True,
) -> None:
    """checkpoint.safetensors (model, AdamW, RNG states, step), then model.safetensors (with_model)."""
    save_checkpoint(out_dir / "checkpoint.safetensors", step, model, optimizer, _rng_state(generator, device))
    if with_model:
        save_model(out_dir / "model.safetensors", model)


def restore_training_state(
    out_dir: Path,
    model: nn.Module,
    optimizer: torch.optim.Optimizer,
    generator: torch.Generator,
    device: torch.device,
) -> int:
    """Load checkpoint.safetensors into model, optimizer and the RNGs; the step to resume from (0 if none)."""
    path = out_dir / "checkpoint.safetensors"
    if not path.exists():
        return 0
    step, rng, _ = load_checkpoint(path, model, optimizer, retrain=retrain_hint(out_dir))
    _set_rng_state(generator, rng, device)
    return step


def _rng_state(generator: torch.Generator, device: torch.device) -> dict[str, Tensor]:
    state = {"data": generator.get_state(), "torch": torch.get_rng_state()}
    if device.type == "cuda":
        state["cuda"] = torch.cuda.get_rng_state(device)
    return state


def _set_rng_state(generator: torch.Generator, state: dict[str, Tensor], device: torch.device) -> None:
    generator.set_state(state["data"])
    torch.set_rng_state(state["torch"])
    if device.type == "cuda" and "cuda" in state:
        torch.cuda.set_rng_state(state["cuda"], device)
