"""Nothing outside its module names an entry: no registered name is a string literal elsewhere in mop/.

Every registry (predictors, families, experiments, analyses, measures, figures) is filled, and each entry's
home is the module that defines it (a learned predictor's home is also its model's module). Then every plain
string literal of mop/ (docstrings and f-string text left out: they describe, they do not select) that equals
a registered name outside that name's home counts. The experiment definitions (mop.experiments.paper) are
data that name the predictors, analyses, measures and figures they use, which is their job; the allow-list
below holds the names that are also ordinary words or config values elsewhere, each with its reason.
"""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

import mop  # noqa: F401 (fills the registries)
import mop.experiments.runner  # noqa: F401 (registers the analyses' measures)
from mop.experiments import EXPERIMENTS
from mop.experiments.analyses import ANALYSES
from mop.experiments.figures import FIGURES
from mop.experiments.measures import MEASURES
from mop.models import registry as models
from mop.predictors import PREDICTORS
from mop.systems.base import FAMILIES

PACKAGE = Path(mop.__file__).resolve().parent
EXPERIMENT_DATA = "mop.experiments.paper"  # experiments as data: they name what they use

# (module, literal) pairs that are not an entry's name there
ALLOWED: dict[tuple[str, str], str] = {}


def homes() -> dict[str, set[str]]:
    """Registered name -> the modules that define an entry of that name (any registry)."""
    out: dict[str, set[str]] = {}
    for registry in (PREDICTORS, FAMILIES, ANALYSES, MEASURES, FIGURES):
        for name in registry.names():
            entry = registry.get(name)
            home = out.setdefault(name, set())
            home.add(entry.__module__)
            arch = registry.meta(name).get("arch")
            if arch:
                home.add(models._MODELS[arch].__module__)
    for name in EXPERIMENTS.names():
        out.setdefault(name, set()).add(EXPERIMENT_DATA)
    return out


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def literals(path: Path) -> list[tuple[str, int]]:
    """(text, line) of every plain string constant that is neither a docstring nor inside an f-string."""
    tree = ast.parse(path.read_text())
    skip: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            if (
                node.body
                and isinstance(node.body[0], ast.Expr)
                and isinstance(node.body[0].value, ast.Constant)
            ):
                skip.add(id(node.body[0].value))
        if isinstance(node, ast.JoinedStr):
            skip.update(id(v) for v in ast.walk(node))
    return [
        (node.value, node.lineno)
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in skip
    ]


def entry_names_outside_their_module() -> list[str]:
    known = homes()
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        module = module_name(path)
        if module == EXPERIMENT_DATA:
            continue
        for text, line in literals(path):
            if text in known and module not in known[text] and (module, text) not in ALLOWED:
                found.append(f"{path.relative_to(PACKAGE.parent)}:{line} names {text!r}")
    return found


def test_no_entry_is_named_outside_its_module():
    found = entry_names_outside_their_module()
    assert not found, f"{len(found)} names of an entry outside its module:\n" + "\n".join(found)


def test_the_scan_sees_a_name_and_skips_docstrings(tmp_path):
    source = tmp_path / "m.py"
    source.write_text('"""kalman in a docstring."""\n\nx = "kalman"\ny = f"{x} kalman"\n')
    assert literals(source) == [("kalman", 3)]
    assert inspect.getsource(literals)  # the scan reads source, not bytecode
