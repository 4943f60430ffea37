"""The `mop` command without the optional extras (the README's quick start installs none).

Every subcommand's --help works; a benchmark that needs a missing extra names it in one line.
"""

import subprocess
import sys

import pytest

from mop.cli import COMMANDS

BLOCK_EXTRAS = "import sys; sys.modules['filterpy'] = None; sys.modules['transformers'] = None; "


def _mop(*argv: str) -> subprocess.CompletedProcess:
    code = BLOCK_EXTRAS + f"from mop.cli import main; sys.exit(main({list(argv)!r}))"
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("command", list(COMMANDS))
def test_help_without_optional_extras(command):
    result = _mop(command, "--help")
    assert result.returncode == 0, result.stderr
    assert "usage: mop " + command in result.stdout


def test_bench_filters_names_the_missing_extra():
    result = _mop("bench", "filters", "--systems", "2", "--loop-systems", "1")
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        "mop: error: mop bench filters (the per-system reference loop) needs filterpy, "
        "which is not installed; run: pip install 'mop[bench]'"
    ]
