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
# modules that are data naming the entries they use: their job, not a special case
DATA_MODULES = {
    "mop.experiments.paper": "the paper's experiments",
    "mop.experiments.missing_data": "the missing-data experiment",
    "mop.experiments.inputs": "the linear-inputs experiment",
    "mop.experiments.classes": "the class-model experiments",
    "mop.pretrained.catalog": "the shipped models: the experiment and family each was trained on",
}

# (module, literal) -> why that literal is not an entry's name there (a key or word that shares the name)
NOT_AN_ENTRY: dict[tuple[str, str], str] = {
    ("mop.benchmarks", "cascaded-tanks"): "the benchmark's name (a registry of benchmarks, not the family)",
    (
        "mop.benchmarks",
        "wiener-hammerstein",
    ): "the benchmark's name (a registry of benchmarks, not the family)",
    ("mop.benchmarks.protocol", "cascaded-tanks"): "the benchmark whose published baselines these are",
    ("mop.benchmarks.protocol", "wiener-hammerstein"): "the benchmark whose published baselines these are",
    ("mop.recipe.selection", "arx"): "the identifier kind mop.identify.fit takes, as `mop fit arx` names it",
    ("mop.commands.benchmark", "arx"): "the fitted identifier `mop benchmark --predictors arx` runs",
    ("mop.bench.freerun", "arx"): "the `mop fit arx` command line it times",
    ("mop.bench.freerun", "mop"): "the program it runs as a subprocess",
    ("mop.commands.benchmark", "mop"): "the learned model trained on the estimation part (--predictors mop)",
    ("mop.commands.benchmark", "rmse"): "results.json's RMSE key",
    ("mop.benchmarks.pages", "rmse"): "results.json's RMSE key, read to write the results pages' tables",
    ("mop.benchmarks.pages", "mop"): "`mop benchmark --predictors mop`, whose rows name their training seed",
    ("mop.commands.benchmark", "wiener-hammerstein"): "the benchmark whose table reads in mV",
    ("mop.checkpoint", "mop"): "the checkpoint file's metadata key",
    ("mop.network_config", "gru"): "model.arch's name for the GRU's network section (the config layer)",
    (
        "mop.network_config",
        "deep-lru",
    ): "model.arch's name for the deep LRU's network section (the config layer)",
    ("mop.cli", "mop"): "the program's name",
    ("mop.report", "mop"): "the package whose version the report prints",
    ("mop.evaluate", "error"): "eval.json's mean-error curve",
    ("mop.metrics", "error"): "eval.json's mean-error curve",
    ("mop.report", "error"): "the forecast table's errors",
    ("mop.pretrained.card", "simulation"): "card.json's simulation section",
    ("mop.pretrained.card", "rmse"): "card.json's simulation table",
    ("mop.pretrained.card", "one_step_rmse_record"): "card.json's simulation table, the t >= 50 column",
    ("mop.plots", "error"): "eval.json's mean-error curve",
    ("mop.experiments.analyses", "error"): "the forecast table's errors",
    ("mop.experiments.figures", "coverage"): "the calibration table's coverage column",
    ("mop.experiments.figures", "excess_mse"): "the slope fit's excess-MSE values",
    ("mop.experiments.figures", "slope"): "the slope fit's slope",
    ("mop.plots", "floor"): "the legend label of the irreducible-error curve",
    ("mop.predictors", "forecast"): "the Predictor method's name",
    ("mop.experiments.analyses", "rmse"): "the simulation table's RMSE column",
    ("mop.commands.bench", "forecast"): "the `mop bench forecast` subcommand",
    ("mop.experiments.pretrained_build", "forecast"): "the Predictor method and the card's forecast table",
    ("mop.experiments.pretrained_build", "error"): "the forecast table's errors",
    ("mop.pretrained.card", "error"): "the forecast table's errors",
    ("mop.pretrained.card", "forecast"): "the card's forecast table",
    (
        "mop.identify.arx",
        "arx",
    ): "the fitted identifier's own name (mop.identify's IDENTIFIERS), not the online predictor",
    ("mop.identify.select", "simulation"): "the --select criterion of mop fit (held-out simulation RMSE)",
    **{
        ("mop.identity", n): "the frozen record of the keys each family's config.json held (run hashes)"
        for n in (
            *("linear", "upper-triangular", "colored-noise", "switching", "linear-inputs", "quadrotor"),
            *("lti-siso", "wiener-hammerstein"),
        )
    },
    ("mop.identify.select", "rmse"): "fitted.json's held-out score key",
}
# A benchmark times and checks the very entries it names (against filterpy and per-system loops), as the
# experiment data names what it runs; each (module, name) is listed, so naming another entry still fails.
BENCHMARKED: dict[tuple[str, str], str] = {
    **{
        ("mop.bench.filters", n): "mop bench filters times these filters against filterpy"
        for n in ("kalman", "rls", "ekf", "n4sid-kf", "linear", "quadrotor")
    },
    ("mop.bench.recipe", "kalman"): "the recipe benchmark's reference (its --reference default)",
    ("mop.bench.recipe", "linear"): "the recipe benchmark's family (its --family default)",
    **{("mop.bench.simulate", n): "mop bench simulate times these families" for n in ("linear", "quadrotor")},
    **{
        ("mop.bench.forecast", n): "mop bench forecast times these predictors on these families"
        for n in ("linear", "colored-noise", "kalman", "kalman-colored", "rls", "mop")
    },
}


def homes() -> dict[str, set[str]]:
    """Registered name -> the modules that define an entry of that name (any registry)."""
    out: dict[str, set[str]] = {}
    for registry in (PREDICTORS, FAMILIES, ANALYSES, MEASURES, FIGURES):
        for name in registry.names():
            entry = registry.get(name)
            home = out.setdefault(name, set())
            home.add(entry.__module__)
            arch = registry.meta(name).get("arch") if registry is PREDICTORS else None
            if arch:
                home.add(models._MODELS[arch].__module__)
    for name in EXPERIMENTS.names():  # an Experiment is an instance: its home is the data module naming it
        home = out.setdefault(name, set())
        home.update(m for m in DATA_MODULES if name in dict(literals(module_file(m))))
    return out


def module_file(module: str) -> Path:
    return PACKAGE.parent.joinpath(*module.split(".")).with_suffix(".py")


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


def entry_names_outside_their_module() -> dict[tuple[str, str], list[str]]:
    """(module, name) -> the "file:line" places where `module` names an entry it does not define."""
    known = homes()
    found: dict[tuple[str, str], list[str]] = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        module = module_name(path)
        if module in DATA_MODULES:
            continue
        for text, line in sorted(set(literals(path)), key=lambda item: item[1]):
            if text in known and module not in known[text] and (module, text) not in NOT_AN_ENTRY:
                found.setdefault((module, text), []).append(f"{path.relative_to(PACKAGE.parent)}:{line}")
    return found


def test_no_entry_is_named_outside_its_module():
    """Library code finds an entry by its metadata (a default, a kind), never by writing its name."""
    found = entry_names_outside_their_module()
    new = {key: places for key, places in found.items() if key not in BENCHMARKED}
    lines = [f"{', '.join(places)} names {name!r}" for (_, name), places in new.items()]
    assert not new, "names of an entry outside its module (register it, or read it from metadata):\n" + (
        "\n".join(lines)
    )
    gone = sorted(set(BENCHMARKED) - set(found))
    assert not gone, f"no longer named, remove from BENCHMARKED: {gone}"


def test_the_scan_sees_a_name_and_skips_docstrings(tmp_path):
    source = tmp_path / "m.py"
    source.write_text('"""kalman in a docstring."""\n\nx = "kalman"\ny = f"{x} kalman"\n')
    assert literals(source) == [("kalman", 3)]


def test_the_scan_finds_a_name_planted_in_the_runner(monkeypatch):
    """A predictor name written into the runner is found (and the built-in homes are where they belong)."""
    known = homes()
    assert known["kalman"] == {"mop.filters.kalman"} and "mop.models.transformer" in known["mop"]
    runner = PACKAGE / "experiments" / "runner.py"
    planted = runner.read_text() + '\nSPECIAL = "kalman"\n'
    original = Path.read_text
    monkeypatch.setattr(Path, "read_text", lambda self: planted if self == runner else original(self))
    found = entry_names_outside_their_module()
    assert list(found.get(("mop.experiments.runner", "kalman"), [])) == [
        f"mop/experiments/runner.py:{planted.count(chr(10))}"
    ]
