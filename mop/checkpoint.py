"""Checkpoints and weights in safetensors + JSON metadata: loading never unpickles.

A checkpoint is one file, written atomically (mop.atomic), so a crash mid-write leaves the previous one whole:
    tensors   "model.<name>"               model parameters and buffers
              "optim.<index>.<key>"        AdamW state (step, exp_avg, exp_avg_sq) per parameter
              "rng.<name>"                 torch.Generator / global RNG states (uint8)
    metadata  "mop": JSON {"step", "param_groups", "extra"}
              "sha256": hex digest over every tensor (name, dtype, shape, bytes; sorted by name)

Every file written here carries the sha256 of its tensors in its metadata; loading recomputes it and
checks that every floating tensor is finite, so bytes overwritten inside a file of the right size (a bad
disk, a partial copy) are refused in one line instead of predicting NaN. Files without a digest (written
before it existed) are still checked for NaN/Inf.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file
from torch import Tensor, nn

from mop.atomic import atomic_path
from mop.errors import MopError


def _contiguous(tensors: dict[str, Tensor]) -> dict[str, Tensor]:
    return {k: v.detach().contiguous().cpu() for k, v in tensors.items()}


def tensors_digest(tensors: dict[str, Tensor]) -> str:
    """sha256 hex digest over the tensors sorted by name: each name, dtype, shape and raw bytes."""
    digest = hashlib.sha256()
    for name in sorted(tensors):
        t = tensors[name].detach().contiguous().cpu()
        digest.update(f"{name}|{t.dtype}|{tuple(t.shape)}|".encode())
        digest.update(t.reshape(-1).view(torch.uint8).numpy())  # the buffer itself, no copy
    return digest.hexdigest()


def _looks_pickled(path: Path) -> bool:
    """A pickle (protocol 2+ starts with 0x80) or a torch.save zip ("PK"), and not safetensors: that starts
    with its header's length (8 bytes, little-endian, whose first byte may well be 0x80) and then "{"."""
    with open(path, "rb") as handle:
        head = handle.read(9)
    size = path.stat().st_size
    if len(head) == 9 and head[8:9] == b"{" and 8 + int.from_bytes(head[:8], "little") <= size:
        return False
    return head[:1] == b"\x80" or head[:2] == b"PK"


def save_tensors(
    path: str | Path, tensors: dict[str, Tensor], metadata: dict[str, str] | None = None
) -> None:
    """Atomically write `tensors` to a safetensors file, with their sha256 in the metadata."""
    tensors = _contiguous(tensors)
    metadata = {**(metadata or {}), "sha256": tensors_digest(tensors)}
    with atomic_path(path) as tmp:
        try:
            save_file(tensors, str(tmp), metadata=metadata)
        except SafetensorError as err:  # an I/O error inside the Rust writer: as the OSError it is
            code = re.search(r"code: (\d+)", str(err))
            if code is None:
                raise
            raise OSError(int(code.group(1)), os.strerror(int(code.group(1))), str(path)) from None
        _sort_metadata(tmp)


def _sort_metadata(path: Path) -> None:
    """Rewrite the header of the safetensors file at `path` with its metadata keys sorted, in place.

    The Rust writer keeps the metadata in a hash map whose order changes from process to process, so a file
    with two or more metadata keys (the weights' "format" and "sha256") would differ in its bytes between two
    writes of the same tensors. Sorting makes the bytes a function of the tensors and metadata alone
    (pretrained builds compare digests of the files). Same keys and values: the header keeps its length."""
    with open(path, "r+b") as f:
        size = int.from_bytes(f.read(8), "little")
        header = json.loads(f.read(size))
        meta = header.get("__metadata__") or {}
        if len(meta) < 2:
            return
        header["__metadata__"] = dict(sorted(meta.items()))
        text = json.dumps(header, separators=(",", ":")).encode()
        if len(text) > size:  # another escaping than the writer's: leave the file as written
            return
        f.seek(8)
        f.write(text.ljust(size, b" "))  # the format pads its header with spaces


def load_tensors(
    path: str | Path, device: str | torch.device = "cpu", retrain: str = ""
) -> tuple[dict[str, Tensor], dict[str, str]]:
    """Read a safetensors file; a missing, truncated, corrupted (checksum, NaN/Inf) or pickled file raises
    MopError. retrain: what to do about a damaged file (e.g. the command that retrains the run)."""
    path = Path(path)
    todo = retrain or "delete it and train again"
    if not path.is_file():
        raise MopError(f"{path} does not exist; train a model first (mop train) or check the run directory")
    if _looks_pickled(path):
        raise MopError(
            f"{path} is a pickle/torch.save file, which mop refuses to load; only safetensors is accepted"
        )
    try:
        from safetensors import safe_open

        with safe_open(str(path), framework="pt") as handle:
            metadata = handle.metadata() or {}
        tensors = load_file(str(path), device="cpu")
    except (SafetensorError, OSError, ValueError, RuntimeError) as err:
        first = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise MopError(
            f"{path} is not a valid safetensors file ({first}); it is truncated or corrupted: {todo}"
        ) from None
    if "sha256" in metadata and tensors_digest(tensors) != metadata["sha256"]:
        raise MopError(f"{path} is damaged (its sha256 differs from the one written with it): {todo}")
    bad = [k for k, v in tensors.items() if v.is_floating_point() and not bool(torch.isfinite(v).all())]
    if bad:
        raise MopError(f"{path} holds NaN/Inf in {len(bad)} tensors (first {bad[0]!r}): {todo}")
    return {k: v.to(device) for k, v in tensors.items()}, metadata


def save_model(path: str | Path, model: nn.Module) -> None:
    save_tensors(path, model.state_dict(), {"format": "pt"})


def load_model_weights(
    path: str | Path,
    model: nn.Module,
    retrain: str = "",
    adapt: Callable[[dict[str, Tensor]], dict[str, Tensor]] | None = None,
) -> None:
    """Load a model.safetensors into `model`; adapt (optional) maps the stored tensors first (a fine-tune
    that drops a read-in channel: mop.recipe.source.load_init)."""
    tensors, _ = load_tensors(path, retrain=retrain)
    _load_state(model, adapt(tensors) if adapt is not None else tensors, path)


def _load_state(model: nn.Module, tensors: dict[str, Tensor], path: str | Path) -> None:
    expected = set(model.state_dict())
    if set(tensors) != expected:
        missing, extra = sorted(expected - set(tensors)), sorted(set(tensors) - expected)
        raise MopError(
            f"{path} does not match the model in config.json (missing {missing[:3]}, unexpected {extra[:3]})"
        )
    try:
        model.load_state_dict(tensors)
    except RuntimeError as err:
        last = str(err).splitlines()[-1].strip()
        raise MopError(f"{path} does not match the model in config.json ({last})") from None


def save_checkpoint(
    path: str | Path,
    step: int,
    model: nn.Module,
    optimizer: torch.optim.Optimizer,
    rng: dict[str, Tensor],
    extra: dict[str, Any] | None = None,
) -> None:
    """Model + optimizer state + RNG states + step in one atomically written safetensors file."""
    tensors = {f"model.{k}": v for k, v in model.state_dict().items()}
    state = optimizer.state_dict()
    for index, slots in state["state"].items():
        for key, value in slots.items():
            tensors[f"optim.{index}.{key}"] = value if torch.is_tensor(value) else torch.tensor(value)
    tensors.update({f"rng.{k}": v for k, v in rng.items()})
    meta = {"step": step, "param_groups": state["param_groups"], "extra": extra or {}}
    save_tensors(path, tensors, {"mop": json.dumps(meta)})


def load_checkpoint(
    path: str | Path, model: nn.Module, optimizer: torch.optim.Optimizer, retrain: str = ""
) -> tuple[int, dict[str, Tensor], dict[str, Any]]:
    """Restore model and optimizer from `path`; returns (step, rng states, extra)."""
    tensors, metadata = load_tensors(path, retrain=retrain)
    if "mop" not in metadata:
        raise MopError(f"{path} is not a mop checkpoint (no metadata); delete it to start over")
    meta = json.loads(metadata["mop"])
    _load_state(model, {k[6:]: v for k, v in tensors.items() if k.startswith("model.")}, path)
    slots: dict[int, dict[str, Tensor]] = {}
    for key, value in tensors.items():
        if key.startswith("optim."):
            _, index, name = key.split(".", 2)
            slots.setdefault(int(index), {})[name] = value
    device = next(model.parameters()).device
    slots = {i: {k: (v if k == "step" else v.to(device)) for k, v in s.items()} for i, s in slots.items()}
    optimizer.load_state_dict({"state": slots, "param_groups": meta["param_groups"]})
    rng = {k[4:]: v for k, v in tensors.items() if k.startswith("rng.")}
    return int(meta["step"]), rng, meta.get("extra", {})
