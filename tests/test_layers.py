"""The layer contract of the package: imports point one way.

An AST walk over mop/ builds the import graph, function-level imports included (an import inside a function
still ties the modules together, it only hides the tie until the call). Importing `mop.a.b` from outside
`mop.a` also runs `mop/a/__init__.py`, so that edge is counted too. The graph must have no cycle, every
import must go to the importer's layer or one below, and no mop module may be imported inside a function
(the CLI picks its subcommand's module with importlib, which is the one place a module is chosen late).
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "mop"

# lowest first; a module belongs to the layer of its longest matching prefix
LAYERS: list[tuple[str, ...]] = [
    ("mop.errors", "mop.registry", "mop.atomic", "mop.progress", "mop.metrics", "mop.io", "mop.report"),
    ("mop.typecheck", "mop.identity"),  # core: they import no mop module
    ("mop.memory", "mop.outputs", "mop.plugins"),  # core too: they import only errors and atomic
    ("mop.missing",),
    ("mop.record",),  # a measured record (mop.io's files read once)
    ("mop.pretrained",),  # the shipped runs' files and cards (mop.runs resolves pretrained:NAME with it)
    ("mop.plots", "mop.checkpoint"),
    # mop.feature_config, mop.network_config: the model's front-end keys and its network's per architecture
    ("mop.systems", "mop.config", "mop.feature_config", "mop.network_config"),
    ("mop.predictors",),
    ("mop.records",),  # a predictor over a user's records and the figures of merit
    ("mop.benchmarks",),  # the benchmarks' splits and protocol
    ("mop.filters",),
    ("mop.identify",),  # fitted identifiers: built on the filters' subspace code, loaded by mop predict
    ("mop.simulators",),  # learned simulators fitted on their simulation error (deep LRU)
    ("mop.peers",),  # the field's tools under mop's protocol (optional extras: sysidentpy)
    ("mop.models", "mop.runs"),
    ("mop.evaluate",),
    ("mop.train",),
    ("mop.experiments",),  # mop.experiments.pretrained_build builds and cards the shipped models
    ("mop.recipe",),  # mop train's config from a user's record: the records and fine-tune recipes
    ("mop.incontext",),  # a record as a learned model's context (its feature fitted on it: models, train)
    ("mop.estimators",),  # ARX, N4SID and the learned model with one face (mop train --data path)
    ("mop.bench",),
    ("mop.commands", "mop.cli", "mop.__main__", "mop"),
]


def module_files() -> dict[str, Path]:
    """Dotted module name -> file, for every module of the package."""
    out = {}
    for path in PACKAGE.rglob("*.py"):
        parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = path
    return out


def _target(name: str, modules: dict[str, Path]) -> str | None:
    """The module that importing `name` (a module or a name inside one) loads."""
    while name and name not in modules:
        name = name.rpartition(".")[0]
    return name or None


def imports_of(module: str, path: Path, modules: dict[str, Path]) -> list[tuple[str, int, bool]]:
    """(imported mop module, line, inside a function) for every import statement in `path`."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found = []

    def visit(node: ast.AST, in_function: bool) -> None:
        for child in ast.iter_child_nodes(node):
            inside = in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            names: list[str] = []
            if isinstance(child, ast.Import):
                names = [alias.name for alias in child.names]
            elif isinstance(child, ast.ImportFrom):
                base = child.module or ""
                if child.level:
                    parts = package.split(".")[: len(package.split(".")) - child.level + 1]
                    base = ".".join(parts + ([base] if base else []))
                # `from mop import plots` imports the module mop.plots; `from mop.x import f` imports mop.x
                names = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in child.names]
            for name in names:
                target = _target(name, modules)
                if target and target != module and target.split(".")[0] == "mop":
                    found.append((target, child.lineno, inside))
            visit(child, inside)

    visit(ast.parse(path.read_text()), False)
    return found


def import_graph() -> tuple[dict[str, set[str]], list[str]]:
    """module -> modules it loads (parent packages of cross-package targets included), and the
    function-level imports as "file:line imports module" lines."""
    modules = module_files()
    graph: dict[str, set[str]] = {m: set() for m in modules}
    late = []
    for module, path in modules.items():
        for target, line, inside in imports_of(module, path, modules):
            if inside:
                where = f"{path.relative_to(PACKAGE.parent)}:{line} imports {target} inside a function"
                late += [] if where in late else [where]
            graph[module].add(target)
            parts = target.split(".")
            for i in range(2, len(parts)):
                parent = ".".join(parts[:i])
                if parent in modules and parent != module and not module.startswith(parent + "."):
                    graph[module].add(parent)
    graph["mop"] |= set(lazy_imports())
    return graph, late


def lazy_imports() -> list[str]:
    """The modules mop/__init__.py loads on first use of an attribute (its LAZY mapping, PEP 562): edges of
    the package like any import."""
    tree = ast.parse((PACKAGE / "__init__.py").read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", "") == "LAZY" for t in node.targets):
            return [v.value for v in node.value.values]
    return []


def test_lazy_attributes_are_counted_as_imports():
    import mop

    assert lazy_imports() == list(mop.LAZY.values()) and "mop.estimators" in import_graph()[0]["mop"]


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out = []

    def strongconnect(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                strongconnect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            strongconnect(v)
    return out


def layer_of(module: str) -> int:
    best, layer = -1, -1
    for i, prefixes in enumerate(LAYERS):
        for prefix in prefixes:
            if (module == prefix or module.startswith(prefix + ".")) and len(prefix) > best:
                best, layer = len(prefix), i
    return layer


def test_every_module_has_a_layer():
    unplaced = [m for m in module_files() if layer_of(m) < 0]
    assert not unplaced, f"add these modules to a layer in tests/test_layers.py: {unplaced}"


def test_no_function_level_import_of_a_mop_module():
    _, late = import_graph()
    assert not late, "move these imports to the top of their module:\n" + "\n".join(late)


def test_imports_point_down():
    graph, _ = import_graph()
    upward = [
        f"{a} (layer {layer_of(a)}) imports {b} (layer {layer_of(b)})"
        for a, targets in sorted(graph.items())
        for b in sorted(targets)
        if layer_of(b) > layer_of(a)
    ]
    assert not upward, "imports that point up a layer (see LAYERS):\n" + "\n".join(upward)


def test_no_import_cycles():
    graph, _ = import_graph()
    found = cycles(graph)
    detail = []
    for component in found:
        inside = set(component)
        edges = [f"  {a} -> {b}" for a in component for b in sorted(graph[a] & inside)]
        detail.append(f"cycle of {len(component)} modules:\n" + "\n".join(edges))
    assert not found, "\n".join(detail)


def test_the_checker_sees_a_cycle_and_a_late_import(tmp_path):
    """The walk itself: a function-level import that closes a loop is found."""
    graph = {"mop.a": {"mop.b"}, "mop.b": {"mop.c"}, "mop.c": {"mop.a"}, "mop.d": {"mop.a"}}
    assert cycles(graph) == [["mop.a", "mop.b", "mop.c"]]
    source = tmp_path / "m.py"
    source.write_text("import mop.errors\n\ndef f():\n    from mop.registry import Registry\n")
    found = imports_of("mop.m", source, {"mop.errors": source, "mop.registry": source, "mop.m": source})
    assert found == [("mop.errors", 1, False), ("mop.registry", 4, True)]


def test_reproduce_imports_no_bench_code():
    """`mop reproduce` loads its own command's module only (an unknown experiment stops it early)."""
    code = (
        "import sys; from mop.cli import main; rc = main(['reproduce', 'no-such-experiment']); "
        "print(rc, sorted(m for m in sys.modules if m.startswith('mop.bench') or m == 'mop.commands.bench'))"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.stdout.split(maxsplit=1) == ["2", "[]\n"], result.stdout + result.stderr
