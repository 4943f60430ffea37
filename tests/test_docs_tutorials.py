"""The documentation runs: the marked code blocks of each page of docs/ (the tutorials, the API examples) are
executed in order, in a fresh folder, as a reader would paste them; the generated reference pages cover every
command and every configuration knob; the README's links point at pages that exist.

A block runs when the line before its opening fence is a marker comment:

    <!-- docs-test: run -->                              python or bash, run in the tutorial's folder
    <!-- docs-test: run; replace "A" "B" -->             the same with the text A replaced by B first
                                                         (a tutorial's real budget cut to a test's)
    <!-- docs-test: file NAME -->                        the block is written to the file NAME

bash blocks run with `set -euo pipefail` and `mop` calling this interpreter's `python -m mop`.
"""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MARKER = re.compile(r"^<!-- docs-test: (run|file) ?(.*?) -->$")
PAGES = sorted(
    p for p in [*(ROOT / "docs").rglob("*.md"), ROOT / "README.md"] if "<!-- docs-test:" in p.read_text()
)
TUTORIALS = sorted((ROOT / "docs" / "tutorials").glob("*.md"))
FENCE = re.compile(r"^```(\w*)")


def marked_blocks(text: str) -> list[tuple[str, str, str, str]]:
    """[(action, argument, language, code)] of the marked fenced blocks of a page, in order."""
    lines, blocks, i = text.splitlines(), [], 0
    while i < len(lines):
        marker = MARKER.match(lines[i].strip())
        fence = FENCE.match(lines[i + 1]) if marker and i + 1 < len(lines) else None
        if not (marker and fence):
            assert not marker, f"a docs-test marker must sit right above a fence: line {i + 1}"
            i += 1
            continue
        end = next(j for j in range(i + 2, len(lines)) if lines[j].startswith("```"))
        code = "\n".join(lines[i + 2 : end]) + "\n"
        blocks.append((marker.group(1), marker.group(2), fence.group(1), code))
        i = end + 1
    return blocks


def replacements(argument: str) -> list[tuple[str, str]]:
    """`; replace "A" "B"` (repeatable) -> [(A, B)]."""
    return re.findall(r'replace "([^"]*)" "([^"]*)"', argument)


def run_block(language: str, code: str, cwd: Path) -> None:
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1", MPLBACKEND="Agg")
    if language == "python":
        argv = [sys.executable, "-c", code]
    elif language == "bash":
        prelude = f'set -euo pipefail\nmop() {{ "{sys.executable}" -m mop "$@"; }}\n'
        argv = ["bash", "-c", prelude + code]
    else:
        raise AssertionError(f"a marked block must be python or bash, got {language!r}")
    done = subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=600)
    output = f"--- stdout\n{done.stdout}\n--- stderr\n{done.stderr}"
    assert done.returncode == 0, f"this block failed:\n{code}\n{output}"


@pytest.mark.slow
@pytest.mark.parametrize("page", PAGES, ids=[p.stem for p in PAGES])
def test_page_runs(page: Path, tmp_path: Path) -> None:
    blocks = marked_blocks(page.read_text())
    assert any(action == "run" for action, *_ in blocks), f"{page.name} has no block marked to run"
    for action, argument, language, code in blocks:
        if action == "file":
            (tmp_path / argument).write_text(code)
            continue
        for old, new in replacements(argument):
            assert old in code, f"{page.name}: the replaced text {old!r} is not in its block"
            code = code.replace(old, new)
        run_block(language, code, tmp_path)


def test_every_tutorial_runs_something():
    assert TUTORIALS and set(TUTORIALS) <= set(PAGES)


def test_markers_are_read():
    """The parser finds what it is given, and a marker away from a fence is refused."""
    text = '<!-- docs-test: run; replace "a b" "c" -->\n```bash\necho a b\n```\n\n```python\nx = 1\n```\n'
    assert marked_blocks(text) == [("run", '; replace "a b" "c"', "bash", "echo a b\n")]
    assert replacements('; replace "a b" "c"') == [("a b", "c")]
    with pytest.raises(AssertionError, match="right above a fence"):
        marked_blocks("<!-- docs-test: run -->\n\n```bash\necho\n```\n")


def _hooks():
    spec = importlib.util.spec_from_file_location("docs_hooks", ROOT / "docs" / "hooks.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_config_knob_has_a_meaning():
    """Each field of ModelConfig, TrainConfig and DataConfig has a meaning in the generated reference (a
    comment at the field in mop/config.py), and the tables list exactly the dataclasses' fields."""
    import dataclasses

    from mop import config

    tables = _hooks().config_knobs()
    for name in ("ModelConfig", "TrainConfig", "DataConfig"):
        keys = [key for key, *_ in tables[name]]
        assert keys == [f.name for f in dataclasses.fields(getattr(config, name))]
        empty = [key for key, _, _, meaning in tables[name] if not meaning.strip()]
        assert not empty, f"{name} fields without a meaning (add a comment in mop/config.py): {empty}"


def test_cli_reference_covers_every_command():
    from mop import cli

    page = _hooks().cli_reference()
    for name in cli.COMMANDS:
        assert f"## `mop {name}`" in page and f"usage: mop {name}" in page


def test_readme_is_a_front_page():
    """At most 200 lines, the two quick-start commands in its first 40, and every local link resolves."""
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= 200
    head = "\n".join(lines[:40])
    assert "mop reproduce linear" in head and "bash scripts/test.sh" in head
    for target in re.findall(r"\]\(([^)#:]+)(?:#[^)]*)?\)", "\n".join(lines)):
        assert (ROOT / target).exists(), f"README links to {target}, which does not exist"


def test_reference_pages_hold_their_generated_text_as_plain_files():
    """docs/reference/*.md read as plain files (on GitHub, from the README's links) hold the generated
    text, current with the code: `python docs/hooks.py` wrote it, and writing it again changes nothing."""
    hooks = _hooks()
    assert hooks.REFERENCE_PAGES
    for page in hooks.REFERENCE_PAGES:
        text = page.read_text()
        assert hooks.committed_text(text) == text, f"{page.name} is stale: run `python docs/hooks.py`"
    cli = (ROOT / "docs" / "reference" / "cli.md").read_text()
    assert "usage: mop predict" in cli and "<!-- /mop:cli -->" in cli
