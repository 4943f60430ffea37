"""MkDocs hooks: the pages that are generated from the code, so they cannot drift from it.

A page holds a marker comment; the hook replaces it with text built from the package at build time:

    <!-- mop:cli -->        `mop COMMAND --help` of every command in mop.cli.COMMANDS (and their subcommands)
    <!-- mop:knobs -->      one table per config dataclass of mop/config.py: key, type, default, meaning (the
                            feature front end's model.* keys from mop/feature_config.py, a table of their own;
                            the network keys each architecture reads, from mop/network_config.py)
    <!-- mop:cards -->      the shipped models' cards, mop/pretrained/*/CARD.md
    <!-- mop:changelog -->  CHANGELOG.md

The functions are plain Python (tests/test_docs_tutorials.py calls them too).
"""

from __future__ import annotations

import argparse
import ast
import importlib.util
import io
import os
import re
import sys
import tokenize
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
KNOB_CLASSES = {"ModelConfig": "model", "TrainConfig": "train", "DataConfig": "data"}


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _help_sections(prog: str, parser: argparse.ArgumentParser, level: int) -> list[str]:
    out = [f"{'#' * level} `{prog}`", "", "```text", parser.format_help().rstrip(), "```", ""]
    for name, sub in _subcommands(parser).items():
        out += _help_sections(f"{prog} {name}", sub, level + 1)
    return out


def cli_reference() -> str:
    """`mop COMMAND --help` for every command the CLI's table names, subcommands nested below."""
    os.environ["COLUMNS"] = "100"  # argparse wraps at the terminal's width: fix it for a stable page
    from mop import cli

    out = []
    for name in cli.COMMANDS:
        parser = _subcommands(cli.build_parser(name))[name]
        out += _help_sections(f"mop {name}", parser, 2)
    return "\n".join(out)


def _comments(source: str) -> dict[int, str]:
    """{line: comment text} of every comment in `source`."""
    found = {}
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            found[tok.start[0]] = tok.string.lstrip("#").strip()
    return found


def _docstring_entries(doc: str, names: list[str]) -> dict[str, str]:
    """'name: text' paragraphs of a class docstring (continuation lines indented), by field name."""
    entries: dict[str, str] = {}
    current = None
    for line in doc.splitlines():
        head = re.match(r"^(\w+(?:, \w+)*)(?: \([^)]*\))?(?:, \w+(?: \([^)]*\))?)*: (.*)$", line)
        if head and not line.startswith(" "):
            keys = [k for k in re.findall(r"\w+", line.split(":")[0]) if k in names]
            current = keys or None
            for key in keys:
                entries[key] = head.group(2)
        elif current and line.startswith(" ") and line.strip():
            for key in current:
                entries[key] += " " + line.strip()
        else:
            current = None
    return entries


def config_knobs(path: Path = ROOT / "mop" / "config.py") -> dict[str, list[tuple[str, str, str, str]]]:
    """{class name: [(key, type, default, meaning)]} of the config dataclasses, read from the source: a
    field's meaning is the comment block right above it and its trailing comment, else its 'name: ...' entry
    in the class docstring, else the block of the field right before it (no blank line between: a group
    such as output_units / input_units shares one comment). A field whose default is FeatureConfig's
    (ModelConfig's feature front end) takes its row from FeatureConfig in mop/feature_config.py."""
    front_end = {row[0]: row for row in _class_rows(path.parent / "feature_config.py")["FeatureConfig"]}
    tables = {}
    for name, rows in _class_rows(path).items():
        if name in KNOB_CLASSES:
            tables[name] = [front_end[r[0]] if r[2].startswith("FeatureConfig.") else r for r in rows]
    return tables


def _class_rows(path: Path) -> dict[str, list[tuple[str, str, str, str]]]:
    """{class name: [(key, type, default, meaning)]} of every class with annotated fields in `path`."""
    source = path.read_text()
    comments = _comments(source)
    lines = source.splitlines()
    tables = {}
    for node in ast.parse(source).body:
        if not isinstance(node, ast.ClassDef):
            continue
        fields = [s for s in node.body if isinstance(s, ast.AnnAssign) and isinstance(s.target, ast.Name)]
        from_doc = _docstring_entries(ast.get_docstring(node) or "", [f.target.id for f in fields])
        rows, previous_end, previous_block = [], -1, ""
        for field in fields:
            above, line = [], field.lineno - 1
            while line in comments and lines[line - 1].lstrip().startswith("#"):
                above.insert(0, comments[line])
                line -= 1
            block = " ".join(above)
            parts = [block, comments.get(field.end_lineno, "")]
            meaning = " ".join(p for p in parts if p) or from_doc.get(field.target.id, "")
            if not meaning and previous_end == field.lineno - 1:
                meaning = previous_block
            previous_end, previous_block = field.end_lineno, block or previous_block * (not meaning)
            default = ast.unparse(field.value) if field.value is not None else ""
            if "default_factory" in default:
                default = "(its own defaults)"
            rows.append((field.target.id, ast.unparse(field.annotation), default, meaning))
        tables[node.name] = rows
    return tables


def knobs_reference() -> str:
    """The knobs page: a table per config class, ModelConfig's in its three groups."""
    front_end = [row[0] for row in _class_rows(ROOT / "mop" / "feature_config.py")["FeatureConfig"]]
    out = []
    for name, rows in config_knobs().items():
        prefix = KNOB_CLASSES[name]
        out += [f"## `{prefix}.*` ({name})", ""]
        groups = [("", rows)]
        if name == "ModelConfig":
            first = next(i for i, row in enumerate(rows) if row[0] in front_end)
            last = first + len(front_end)
            groups = [
                ("The network", rows[:first]),
                ("The feature front end (`mop.feature_config.FeatureConfig`)", rows[first:last]),
                ("The multi-step read-out", rows[last:]),
            ]
        for title, group in groups:
            out += [f"### {title}", ""] if title else []
            out += ["| key | type | default | meaning |", "|---|---|---|---|"]
            for key, kind, default, meaning in group:
                cell = meaning.replace("|", "\\|")
                out.append(f"| `{prefix}.{key}` | `{kind}` | `{default}` | {cell} |")
            out.append("")
            if title == "The network":
                out += [*network_sections(prefix), ""]
    return "\n".join(out)


def network_sections(prefix: str) -> list[str]:
    """The network keys each architecture reads: its section in mop/network_config.py, found by name (the
    file is loaded by path, so the page shows this tree's sections whichever mop is installed)."""
    path = ROOT / "mop" / "network_config.py"
    spec = importlib.util.spec_from_file_location("_docs_network_config", path)
    network_config = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = network_config  # dataclasses looks its module up
    spec.loader.exec_module(network_config)

    out = ["Each architecture reads its own network keys (`mop.network_config`, checked by its section):", ""]
    for arch in network_config.network_config_names():
        section = network_config.network_config_class(arch)
        keys = ", ".join(f"`{prefix}.{key}`" for key in section.keys())
        out.append(f'- `{prefix}.arch = "{arch}"` (`{section.__name__}`): {keys}')
    generic = network_config.GenericNetworkConfig.__name__
    out.append(f"- any other architecture (`{generic}`): every network key, with every check")
    return out


def cards_page() -> str:
    """Every shipped model's CARD.md, its headings one level down."""
    out = []
    for card in sorted((ROOT / "mop" / "pretrained").glob("*/CARD.md")):
        text = card.read_text()
        out.append(re.sub(r"^(#+) ", lambda m: "#" + m.group(1) + " ", text, flags=re.M).rstrip() + "\n")
    return "\n".join(out)


def changelog() -> str:
    text = (ROOT / "CHANGELOG.md").read_text()
    return text.split("\n", 1)[1] if text.startswith("# ") else text


GENERATORS = {
    "<!-- mop:cli -->": cli_reference,
    "<!-- mop:knobs -->": knobs_reference,
    "<!-- mop:cards -->": cards_page,
    "<!-- mop:changelog -->": changelog,
}

# The reference pages are also read as plain files (on GitHub, from the README's links), where neither this
# hook nor mkdocstrings runs. So their generated text is committed: `python docs/hooks.py` writes it and
# tests/test_docs_tutorials.py checks that it is current.
#   <!-- mop:cli --> ... <!-- /mop:cli -->   (and knobs): the generated text between the two markers;
#   after each `::: NAME` directive, <!-- mop:doc NAME --> ... <!-- /mop:doc -->: NAME's signature and
#   docstring as plain text, which the site drops (mkdocstrings renders the directive there).
COMMITTED = {"cli": cli_reference, "knobs": knobs_reference}
REFERENCE_PAGES = sorted((ROOT / "docs" / "reference").glob("*.md"))
DOC_REGION = re.compile(r"\n<!-- mop:doc (\S+) -->\n.*?<!-- /mop:doc -->\n", re.S)


def _object(name: str):
    module, _, attr = name, "", ""
    while True:
        try:
            obj = importlib.import_module(module)
            break
        except ModuleNotFoundError:
            module, _, last = module.rpartition(".")
            attr = f"{last}.{attr}" if attr else last
    for part in filter(None, attr.split(".")):
        obj = getattr(obj, part)
    return obj


def doc_text(name: str) -> str:
    """NAME's signature (where it has one) and docstring, as a plain-text block."""
    import inspect

    obj = _object(name)
    head = name
    if callable(obj) and not inspect.ismodule(obj):
        try:
            signature = str(inspect.signature(obj))
            head = name if signature == "(*args, **kwargs)" else f"{name}{signature}"
        except (TypeError, ValueError):
            pass
    own = obj.__dict__.get("__doc__") if inspect.isclass(obj) else obj.__doc__  # not an inherited one
    doc = inspect.cleandoc(own) if own else ""
    return f"```text\n{head}\n\n{doc}\n```\n"


def committed_text(markdown: str) -> str:
    """The page with its committed regions generated anew (see COMMITTED)."""
    for key, make in COMMITTED.items():
        begin, end = f"<!-- mop:{key} -->", f"<!-- /mop:{key} -->"
        if begin in markdown:
            head, rest = markdown.split(begin, 1)
            tail = rest.split(end, 1)[1] if end in rest else rest
            markdown = f"{head}{begin}\n{make().strip()}\n{end}{tail}"
    markdown = DOC_REGION.sub("\n", markdown)
    lines, out, i = markdown.split("\n"), [], 0
    while i < len(lines):
        out.append(lines[i])
        if lines[i].startswith("::: "):
            name = lines[i][4:].strip()
            i += 1
            while i < len(lines) and lines[i].startswith("    "):
                out.append(lines[i])
                i += 1
            out += ["", f"<!-- mop:doc {name} -->", doc_text(name).rstrip(), "<!-- /mop:doc -->"]
            continue
        i += 1
    return re.sub(r"(<!-- /mop:doc -->)\n\n+", r"\1\n\n", "\n".join(out))


def on_page_markdown(markdown: str, page, config, files) -> str:  # noqa: ARG001 (MkDocs' hook signature)
    markdown = DOC_REGION.sub("\n", markdown)  # the site renders the ::: directives themselves
    for key, make in COMMITTED.items():
        begin, end = f"<!-- mop:{key} -->", f"<!-- /mop:{key} -->"
        if begin in markdown and end in markdown:
            head, rest = markdown.split(begin, 1)
            markdown = f"{head}{begin}\n{make().strip()}\n{end}{rest.split(end, 1)[1]}"
    for marker, make in GENERATORS.items():
        key = marker[len("<!-- mop:") : -len(" -->")]
        if marker in markdown and key not in COMMITTED:
            markdown = markdown.replace(marker, make())
    return markdown


if __name__ == "__main__":  # write the committed regions of the reference pages
    for path in REFERENCE_PAGES:
        path.write_text(committed_text(path.read_text()))
