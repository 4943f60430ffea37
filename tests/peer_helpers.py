"""What the peers' tests (tests/test_narx_peer.py, test_subnet_peer.py) share: a record split into the
est.csv and val.csv that `mop benchmark --est --test` reads, and a peer's library made missing."""

import importlib

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
