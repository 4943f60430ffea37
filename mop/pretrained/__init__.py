"""Shipped pretrained predictors: `pretrained:NAME` works wherever a run directory is accepted.

Each shipped model is a run directory inside the package, installed by pip with it:

    mop/pretrained/<name>/config.json        RunConfig (as `mop train` writes it)
    mop/pretrained/<name>/model.safetensors  the weights
    mop/pretrained/<name>/card.json          what the build measured, and the SHA-256 of the two files above
    mop/pretrained/<name>/CARD.md            the card, rendered from card.json (mop.pretrained.card)

Loading a shipped model checks both SHA-256 digests first, so tampered or truncated weights are refused
with a one-line MopError. `mop pretrained build` (mop.experiments.pretrained_build) rebuilds them.
This module imports nothing of mop above the errors, so the run loader (mop.runs) can use it.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

from mop.errors import MopError, NoPretrainedModel
from mop.pretrained.catalog import CATALOG

PREFIX = "pretrained:"
ROOT = Path(__file__).resolve().parent
HASHED_FILES = ("config.json", "model.safetensors")


def is_pretrained(spec: str | os.PathLike) -> bool:
    """True for a `pretrained:NAME` spec (a string; a Path is always a run directory)."""
    return isinstance(spec, str) and spec.startswith(PREFIX)


def shipped_names(root: Path | None = None) -> list[str]:
    """The names of the shipped models (directories with a card.json), sorted."""
    root = ROOT if root is None else root
    return sorted(p.parent.name for p in root.glob("*/card.json"))


def shipped_dir(name: str, root: Path | None = None) -> Path:
    """The directory of shipped model `name`; NoPretrainedModel naming the shipped ones when there is none."""
    root = ROOT if root is None else root
    path = root / name
    if not name or "/" in name or not (path / "card.json").is_file():
        known = ", ".join(f"{PREFIX}{n}" for n in shipped_names(root)) or "none"
        raise NoPretrainedModel(
            f"no pretrained model {name!r} is shipped; shipped: {known} (see: mop pretrained)"
        )
    return path


def read_card(name: str, root: Path | None = None) -> dict[str, Any]:
    """card.json of shipped model `name` (what its build measured)."""
    root = ROOT if root is None else root
    path = shipped_dir(name, root) / "card.json"
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError:
        raise MopError(f"{path} is not valid JSON; the shipped model is damaged (reinstall mop)") from None


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def file_digests(run_dir: Path) -> dict[str, str]:
    """{file name: SHA-256 hex} of the files of a run that define the predictor (config and weights)."""
    return {name: sha256(run_dir / name) for name in HASHED_FILES}


def verify(name: str, root: Path | None = None) -> Path:
    """The directory of shipped model `name` after checking its files against the card's SHA-256 digests."""
    root = ROOT if root is None else root
    path = shipped_dir(name, root)
    expected = read_card(name, root).get("sha256", {})
    for file in HASHED_FILES:
        if not (path / file).is_file():
            raise MopError(
                f"{PREFIX}{name}: {file} is missing; reinstall mop or rebuild: mop pretrained build {name}"
            )
        if sha256(path / file) != expected.get(file):
            raise MopError(
                f"{PREFIX}{name}: {file} does not match the SHA-256 in its card (tampered or truncated); "
                f"reinstall mop or rebuild it: mop pretrained build {name}"
            )
    return path


def resolve_run_dir(spec: str | os.PathLike) -> Path:
    """A run directory for `spec`: `pretrained:NAME` -> the verified shipped directory, else Path(spec)."""
    if is_pretrained(spec):
        return verify(spec[len(PREFIX) :])
    return Path(spec)


def dimensions(model: dict[str, Any]) -> tuple[int, int]:
    """(m outputs, k inputs) a saved model config (config.json's "model") reads: d_in = m + k (+ m mask)."""
    m = int(model.get("output_dim", 0))
    mask = m if model.get("observation_mask") else 0
    return m, int(model.get("input_dim", 0)) - m - mask


def fitting(outputs: int, inputs: int, root: Path | None = None) -> list[str]:
    """`pretrained:NAME` of the shipped models that read m = outputs outputs and k = inputs inputs."""
    root = ROOT if root is None else root
    found = []
    for name in shipped_names(root):
        try:
            model = json.loads((root / name / "config.json").read_text()).get("model", {})
        except (OSError, json.JSONDecodeError):
            continue  # a damaged one is refused when loaded by name
        if dimensions(model) == (outputs, inputs):
            found.append(PREFIX + name)
    return found


def fitting_hint(outputs: int, inputs: int) -> str:
    """What to use for data of m outputs and k inputs: the shipped models that fit, or how to train one."""
    found = fitting(outputs, inputs)
    if found:
        return f"shipped models for m={outputs}, k={inputs}: {', '.join(found)}"
    return (
        f"no shipped model reads m={outputs}, k={inputs} (see: mop pretrained); train one on your data: "
        "mop train --data FILE --out DIR"
    )


def find_shipped(config: dict[str, Any], root: Path | None = None, experiment: str = "") -> str | None:
    """`pretrained:NAME` of a shipped model trained on the data distribution of `config` (a RunConfig as a
    dict: the same system config, model architecture and read-out, no recorded data), else None. Where
    several are (pretrained:duffing and its records start share a class), the one the catalog says
    `experiment` built comes first."""
    root = ROOT if root is None else root
    if config.get("data") is not None:
        return None
    found = []
    for name in shipped_names(root):
        try:
            saved = json.loads((root / name / "config.json").read_text())
        except (OSError, json.JSONDecodeError):
            continue  # a damaged one is refused when loaded by name; it matches nothing here
        model = saved.get("model", {})
        same_model = all(model.get(k) == config["model"][k] for k in ("arch", "readout"))
        if saved.get("system") == config["system"] and same_model and saved.get("data") is None:
            found.append(name)
    built = {entry.name for entry in CATALOG if entry.experiment == experiment}
    found.sort(key=lambda name: name not in built)  # stable: otherwise the names' order
    return PREFIX + found[0] if found else None
