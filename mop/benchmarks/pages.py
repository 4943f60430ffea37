"""Results pages whose tables are what `mop benchmark` wrote: each table of a page is generated from the
results files it names, so a page cannot show a number that its committed files do not hold.

A table is a marker comment followed by the table, which `render` writes and tests/test_results_pages.py
checks, for every page under docs/results:

    <!-- results-table: cascaded-tanks data/tanks-seed0.json data/tanks-seed1.json -->
    | predictor | test (n = 5) |
    |---|---|
    | arx | 0.6269 |
    ...

A table written by `mop reproduce` (its summary.md, an experiment's report.md) is copied as it is:

    <!-- results-copy: data/paper-small/summary.md -->       the file's first table; FILE#K its K-th (1-based)

Each results-table file is a results.json of `mop benchmark` copied beside the page (paths relative to
it), with its provenance (command, commit, machine, date). A row is one predictor of one file, labelled
with the seed of the file's command where MOP trained (and its `--train` keys; "mop:network" and
"mop:feature", the candidates its held-out check did not keep, as the network or the feature alone); then
the best published baseline and the state of the art (mop.benchmarks.protocol) where known; a row that
another file gives already, label and values alike (the fitted ARX of every run), is shown once. Values are in
the units the field publishes (mV, mm: Benchmark.shown).
`python -m mop.benchmarks.pages PAGE.md` rewrites every table of a page from its files.
"""

from __future__ import annotations

import json
import math
import re
import shlex
import sys
from pathlib import Path

from mop.benchmarks import BENCHMARKS
from mop.benchmarks.protocol import ALONE, PUBLISHED, STATE_OF_THE_ART
from mop.errors import MopError

MARKER = re.compile(r"^<!-- results-table: (\S+) (.+?) -->$")
COPY = re.compile(r"^<!-- results-copy: (\S+?)(?:#(\d+))? -->$")
LEARNED = ("mop", "finetune:", "lru", "subnet")  # predictors whose result depends on the training seed


def _seed(command: str) -> int | None:
    words = shlex.split(command)
    return int(words[words.index("--seed") + 1]) if "--seed" in words else 0


def _training_keys(command: str) -> str:
    """The `--train KEY=VALUE` keys of a `mop benchmark` command, joined ("" where none)."""
    words = shlex.split(command)
    return " ".join(words[i + 1] for i, w in enumerate(words[:-1]) if w == "--train")


def _budget(command: str) -> str:
    """ ", budget B min" where a `mop benchmark` command names --budget B ("" where it trains the default)."""
    words = shlex.split(command)
    given = [words[i + 1] for i, w in enumerate(words[:-1]) if w == "--budget"]
    return f", budget {given[-1]} min" if given else ""


def _cell(rmse: float, scale: float) -> str:
    return "diverged" if math.isinf(rmse) else f"{rmse * scale:.4g}"


def render(bench: str, files: list[Path]) -> list[str]:
    """The table's lines for benchmark `bench` from its results files (see the module docstring)."""
    units, scale = BENCHMARKS.get(bench).shown_units()
    rows, tests = [], None
    for path in files:
        if not path.is_file():
            raise MopError(f"results table: {path} does not exist; copy the results.json of `mop benchmark`")
        data = json.loads(path.read_text())
        if bench not in data:
            raise MopError(f"results table: {path} holds no results of {bench}")
        results, seed = data[bench], _seed(data["provenance"]["command"])
        keys = _training_keys(data["provenance"]["command"])
        order = list(results)
        if tests is None:
            tests = {t: next(iter(results[t].values()))["n"] for t in order}
        for predictor in results[order[0]]:
            learner, _, part = predictor.rpartition(":")
            if learner and part in ALONE:  # a candidate the run's check did not keep (mop:feature, ...)
                name = f"mop ({keys})" if keys and learner == "mop" else learner
                label = f"{name}, {ALONE[part]}"
            else:
                label = f"mop ({keys})" if keys and predictor == "mop" else predictor
            if predictor.startswith(LEARNED):
                label = f"{label}{_budget(data['provenance']['command'])}, seed {seed}"
            cells = [_cell(results[t][predictor]["rmse"], scale) for t in tests]
            row = f"| {label} | " + " | ".join(cells) + " |"
            if row not in rows:  # the fitted models every file of one benchmark holds: shown once
                rows.append(row)
    published = PUBLISHED.get(bench, {})
    if published:
        cells = []
        for t in tests:
            known = published.get(t, {})
            low = min(known.values(), default=None)
            names = ", ".join(k for k, v in known.items() if v == low)
            cells.append("-" if low is None else f"{_cell(low, scale)} ({names})")
        rows.append("| best published baseline (Champneys et al. 2024) | " + " | ".join(cells) + " |")
    sota = STATE_OF_THE_ART.get(bench, {})
    if sota:
        cells = [_cell(sota[t][0], scale) if t in sota else "-" for t in tests]
        rows.append("| state of the art (black box) | " + " | ".join(cells) + " |")
    header = "| predictor (" + units + ") | " + " | ".join(f"{t} (n = {n})" for t, n in tests.items()) + " |"
    return [header, "|---" * (1 + len(tests)) + "|", *rows]


def markdown_tables(text: str) -> list[list[str]]:
    """The tables of a markdown text, each as its lines."""
    found, current = [], []
    for line in text.splitlines() + [""]:
        if line.startswith("|"):
            current.append(line)
        elif current:
            found.append(current)
            current = []
    return found


def copied(path: Path, index: int = 1) -> list[str]:
    """The index-th table (1-based) of a markdown file that `mop reproduce` wrote."""
    if not path.is_file():
        raise MopError(f"results table: {path} does not exist; copy the file `mop reproduce` wrote")
    found = markdown_tables(path.read_text())
    if not 1 <= index <= len(found):
        raise MopError(f"results table: {path} has {len(found)} table(s), not a table {index}")
    return found[index - 1]


def expected(bench: str, files: list[Path]) -> list[str]:
    """What a marked table must be: rendered from results.json files (bench a benchmark's name) or copied
    from a markdown file (bench "copy:K")."""
    if bench.startswith("copy:"):
        return copied(files[0], int(bench.split(":")[1]))
    return render(bench, files)


def tables(page: Path) -> list[tuple[int, str, list[Path], list[str]]]:
    """[(line of the marker, kind, files, the table's lines as written)] of a page; every table of the
    page, marked or not (an unmarked one has kind ""). The kind is a benchmark's name (results-table) or
    "copy:K" (results-copy of a file's K-th table)."""
    lines = page.read_text().splitlines()
    found, i = [], 0
    while i < len(lines):
        if lines[i].startswith("|"):
            start = i
            while i < len(lines) and lines[i].startswith("|"):
                i += 1
            marker = MARKER.match(lines[start - 1]) if start else None
            copy = COPY.match(lines[start - 1]) if start else None
            if marker is not None:
                bench, files = marker.group(1), marker.group(2).split()
            elif copy is not None:
                bench, files = f"copy:{copy.group(2) or 1}", [copy.group(1)]
            else:
                bench, files = "", []
            found.append((start - 1, bench, [page.parent / f for f in files], lines[start:i]))
            continue
        i += 1
    return found


def rewrite(page: Path) -> None:
    """Every marked table of `page` rendered again from its files."""
    lines = page.read_text().splitlines()
    for marker, bench, files, table in reversed(tables(page)):
        if bench:
            lines[marker + 1 : marker + 1 + len(table)] = expected(bench, files)
    page.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    for name in sys.argv[1:]:
        rewrite(Path(name))
