"""Experiments written as TOML or JSON files, without Python; the fields are those of Experiment.

    name = "pendulum"
    title = "a damped pendulum with random parameters"
    plugins = ["pendulum.py"]            # Python files imported first (relative to this file): they register
                                         # families / predictors / figures the experiment names
    predictors = ["mop", "ekf", "ukf", "pf", "last"]
    reference = "ekf"
    [train]
    "system.family" = "pendulum"
    [runs]                               # optional: load a learned predictor instead of training it
    mop = "pretrained:linear"            # (a run directory, relative to this file, or a shipped model)
    [[conditions]]
    name = "test"
    horizon = 50
    [[claims]]
    text = "MOP beats the EKF after 20 steps"
    measure = { metric = "mse_ratio", window = [20, 51] }
    op = "<"
    threshold = 1.0

A threshold is a number, [low, high] with op "between", or a measure table.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from mop.config import from_dict
from mop.errors import MopError
from mop.experiments.spec import Claim, Condition, Experiment, Measure
from mop.plugins import import_plugin
from mop.pretrained import is_pretrained


def is_experiment_file(name: str) -> bool:
    return Path(name).suffix in (".toml", ".json")


def load_experiment(path: str | Path) -> Experiment:
    """Read an experiment file (importing its plugins first); every problem is a one-line MopError."""
    path = Path(path)
    if not path.is_file():
        raise MopError(f"experiment file {path} does not exist")
    data = _read(path)
    if not isinstance(data, dict):
        raise MopError(f"{path}: an experiment file is a table of fields, got {type(data).__name__}")
    for plugin in _names(data.pop("plugins", []), f"{path}: plugins"):
        import_plugin(path.parent / plugin)
    _resolve_paths(data, path.parent)
    return experiment_from_dict(data, str(path))


def _resolve_paths(data: dict[str, Any], root: Path) -> None:
    """Data files and run directories named in the experiment (train "data.path", conditions' "data",
    `runs` values other than pretrained:NAME) are relative to it."""
    at = lambda p: p if not p or Path(p).is_absolute() or is_pretrained(p) else str(root / p)  # noqa: E731
    if isinstance(data.get("train"), dict) and "data.path" in data["train"]:
        data["train"]["data.path"] = at(data["train"]["data.path"])
    tables = [data, *data.get("conditions", [])]
    for table in tables:
        if isinstance(table, dict) and "data" in table and table is not data:
            table["data"] = at(table["data"])
        if isinstance(table, dict) and isinstance(table.get("runs"), dict):
            table["runs"] = {k: at(v) if isinstance(v, str) else v for k, v in table["runs"].items()}


def _read(path: Path) -> dict[str, Any]:
    try:
        if path.suffix == ".json":
            return json.loads(path.read_text())
        try:
            import tomllib
        except ModuleNotFoundError:  # Python 3.10
            import tomli as tomllib
        return tomllib.loads(path.read_text())
    except (ValueError, UnicodeDecodeError) as err:
        raise MopError(
            f"{path} is not valid {path.suffix[1:].upper()} ({str(err).splitlines()[0]})"
        ) from None


def _names(value: Any, where: str) -> list[str]:
    """A list of names; one name given as a string is a list of one (`predictors = "mop"`)."""
    if isinstance(value, str):
        return [value]
    if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
        raise MopError(f"{where} must be a list of names, got {value!r}")
    return list(value)


def _tables(value: Any, where: str) -> list[dict]:
    if isinstance(value, dict):
        value = [value]
    if not isinstance(value, (list, tuple)) or not all(isinstance(v, dict) for v in value):
        example = f"[[{where.split()[-1]}]]"
        raise MopError(f"{where} must be a list of tables ({example} in TOML), got {value!r}")
    return list(value)


def _measure(data: Any, where: str) -> Measure:
    if not isinstance(data, dict):
        raise MopError(f'{where}: a measure is a table like {{ metric = "mse_ratio" }}, got {data!r}')
    data = dict(data)
    if isinstance(data.get("window"), list):
        data["window"] = tuple(data["window"])
    return from_dict(Measure, data, f"{where}.")


def _claim(data: dict, where: str) -> Claim:
    data = dict(data)
    data["measure"] = _measure(data.get("measure"), f"{where}.measure")
    threshold = data.get("threshold")
    if isinstance(threshold, dict):
        data["threshold"] = _measure(threshold, f"{where}.threshold")
    elif isinstance(threshold, list):
        data["threshold"] = tuple(threshold)
    return from_dict(Claim, data, f"{where}.")


def _condition(data: dict, where: str) -> Condition:
    data = dict(data)
    if "predictors" in data:
        data["predictors"] = tuple(_names(data["predictors"], f"{where}.predictors"))
    if isinstance(data.get("x"), list):
        data["x"] = tuple(data["x"])
    return from_dict(Condition, data, f"{where}.")


def experiment_from_dict(data: dict[str, Any], where: str = "experiment") -> Experiment:
    """The Experiment of a file's table; a problem is a MopError starting with `where` (the file's name),
    outside any quoted key: "exp.toml: unknown config key 'conditions[0].horizn'; ..."."""
    try:
        return _experiment(data)
    except MopError as err:
        raise MopError(f"{where}: {err}") from None


def _experiment(data: dict[str, Any]) -> Experiment:
    data = dict(data)
    for key in ("predictors", "analyses", "figures", "panel"):
        if key in data:
            data[key] = tuple(_names(data[key], key))
    if "conditions" in data:
        data["conditions"] = tuple(
            _condition(c, f"conditions[{i}]") for i, c in enumerate(_tables(data["conditions"], "conditions"))
        )
    if "claims" in data:
        claims = _tables(data["claims"], "claims")
        data["claims"] = tuple(_claim(c, f"claims[{i}]") for i, c in enumerate(claims))
    for key in ("name", "title", "train", "predictors"):
        if key not in data:
            raise MopError(f"missing required field {key!r}")
    return from_dict(Experiment, data, "")
