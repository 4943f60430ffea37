"""A fitted identifier on disk: a directory holding fitted.json (kind, orders, the model's matrices as lists,
the estimation file's name, the selection criterion and the held-out score of every order of the grid),
written atomically (mop.atomic: a crash leaves the previous file whole)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from mop.atomic import write_json
from mop.errors import MopError
from mop.identify.linear import IDENTIFIERS, FittedPredictor, LinearModel
from mop.identify.narx_model import KIND as NARX_KIND
from mop.identify.narx_model import FittedNARX

FILE = "fitted.json"
FORMAT = 1


def is_fitted(path: str | os.PathLike) -> bool:
    """Whether `path` is a directory written by save (it holds fitted.json)."""
    return (Path(path) / FILE).is_file()


def save(predictor: FittedPredictor, out: str | os.PathLike) -> Path:
    """Write `out`/fitted.json; MopError if `out` is a file or a directory holding other things (a run)."""
    out = Path(out)
    if out.exists() and (not out.is_dir() or any(p.name != FILE for p in out.iterdir())):
        raise MopError(f"--out {out} exists and is not a fitted model's directory; choose a new name")
    path = out / FILE
    write_json(path, {"format": FORMAT, **predictor.to_json()})
    return path


def load(path: str | os.PathLike) -> FittedPredictor | FittedNARX:
    """The FittedPredictor (or the records recipe's FittedNARX) saved in directory `path`; MopError naming the
    file if it is damaged."""
    file = Path(path) / FILE
    try:
        d = json.loads(file.read_text())
        if d.get("kind") == NARX_KIND:
            return FittedNARX.from_json(d)
        identifier = IDENTIFIERS.get(d["kind"])
        model = LinearModel(**{k: np.asarray(v, dtype=np.float64) for k, v in d["model"].items()})
        m, k, n = int(d["output_dim"]), int(d["input_dim"]), len(model.x0)
        shapes = {"A": (n, n), "B": (n, k), "C": (m, n), "K": (n, m), "b": (n,), "d": (m,)}
        wrong = [name for name, shape in shapes.items() if getattr(model, name).shape != shape]
        if wrong:
            raise ValueError(f"{', '.join(wrong)} of the wrong shape")
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise MopError(
            f"{file} is damaged ({type(e).__name__}: {e}); fit the model again (mop fit)"
        ) from None
    info = {
        k: v
        for k, v in d.items()
        if k not in ("format", "kind", "orders", "output_dim", "input_dim", "model")
    }
    return FittedPredictor(d["kind"], d["orders"], model, m, k, info, lag_state=identifier.lag_state)
