"""What the peers' tests (tests/test_narx_peer.py, test_subnet_peer.py) share: a record split into the
est.csv and val.csv that `mop benchmark --est --test` reads, a peer's library made missing, and the
benchmark's refusal without it."""

import importlib

from mop.cli import main
from mop.record import Record


def write_split(rec: Record, folder, cut: int) -> list[str]:
    """est.csv (rec's first `cut` steps) and val.csv (the rest) in folder: `mop benchmark --est --test`."""
    for name, part in (("est", slice(0, cut)), ("val", slice(cut, len(rec.y)))):
        rows = "\n".join(f"{a:.10g},{b:.10g}" for a, b in zip(rec.y[part, 0], rec.u[part, 0], strict=True))
        (folder / f"{name}.csv").write_text("y0,u0\n" + rows + "\n")
    return ["benchmark", "--est", str(folder / "est.csv"), "--test", str(folder / "val.csv")]


def without_library(monkeypatch, peer, library: str) -> None:
    """The peer module's importlib.import_module raises ImportError for `library` and its submodules."""
    real = importlib.import_module

    def missing(name, *args):
        if name.startswith(library):
            raise ImportError(name)
        return real(name, *args)

    monkeypatch.setattr(peer.importlib, "import_module", missing)


def refused_without_library(argv: list[str], name: str, install: str, out, capsys) -> None:
    """`mop benchmark ... --predictors arx,NAME` without the peer's library (without_library): exit 2, one
    line naming the install, and nothing written to `out`, before any fit."""
    assert main([*argv, "--predictors", f"arx,{name}", "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and install in err and not out.exists()
