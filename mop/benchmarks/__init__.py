"""The nonlinear system-identification benchmarks, split as their official loader splits them.

Each benchmark is an estimation part and one or more test records (mop.record.Record), every test with its
state-initialization window n (Record.init_window): the official protocol fits on the estimation part only,
gives a model each test's input and its first n measured outputs, simulates the rest from the input alone
and scores the RMSE of y[n:] in the output's units (mop.benchmarks.protocol).

The splits, windows and file names are those of the `nonlinear_benchmarks` package (the benchmarks' official
loader, nonlinearbenchmark.org), as its source on GitHub (GerbenBeintema/nonlinear_benchmarks, file
nonlinear_benchmarks/benchmarks.py, commit 0f8f7ac) defines them; tests/test_benchmarks.py holds the numbers
transcribed from that file. Where the PyPI release 1.0.1 differs (it still gives n = 50 for the cascaded tanks
and n = 10 for CED), the repository's code is followed, as the benchmarks' own pages now give it. The F-16
has no window in the loader; n = 50 is mop's choice, stated in every report. Files are found, in order:
1. in a folder given as `--data-dir DIR` or the MOP_BENCHMARK_DATA environment variable, laid out either as
   the benchmarks' authors publish the CSV files (DIR/silverbox/SNLS80mV.csv, DIR/f16/F16Data_*.csv) or as
   the official loader's cache (DIR/Silverbox/SilverboxFiles/SNLS80mV.mat, DIR/F16/F16GVT_Files/...);
2. else through the official loader itself (`pip install mop[benchmarks]`), which downloads them.
Where none is there, a one-line MopError names the files and where to put them.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np

from mop.errors import MopError
from mop.record import Record
from mop.registry import Registry

ENV_VAR = "MOP_BENCHMARK_DATA"


@dataclasses.dataclass(frozen=True)
class Split:
    """A benchmark's estimation records and its test records (each test with its init_window)."""

    name: str
    estimation: list[Record]
    tests: list[Record]
    units: str  # of the outputs, for the tables


@dataclasses.dataclass(frozen=True)
class Benchmark:
    """A benchmark: how to read its files from a folder and split them."""

    name: str
    title: str
    units: str
    files: tuple[str, ...]  # where they go, relative to --data-dir (the CSV layout, then the cache's)
    load: Callable[[Path], Split]  # the folder holding the files -> the official split
    official: str  # the official loader's function, to fetch the files with it
    shown: tuple[str, float] | None = None  # (units, scale) the field publishes in, e.g. ("mV", 1e3)

    def shown_units(self) -> tuple[str, float]:
        """(units, factor from the output's units): the units the field's tables use for this benchmark."""
        return self.shown or (self.units, 1.0)


BENCHMARKS: Registry = Registry("benchmark")


def _csv_columns(path: Path) -> dict[str, np.ndarray]:
    """{column name: values} of a benchmark CSV as its authors publish it (quoted names, a trailing comma;
    an empty cell, as below F-16's one Fs value, is NaN)."""
    with open(path) as f:
        names = [c.strip().strip('"') for c in f.readline().strip().split(",")]
    values = np.genfromtxt(path, delimiter=",", skip_header=1, usecols=[i for i, n in enumerate(names) if n])
    return dict(zip([n for n in names if n], values.T, strict=True))


def _mat(path: Path) -> dict[str, np.ndarray]:
    from scipy.io import loadmat  # scipy is a dependency; imported here only for the .mat layout

    return loadmat(path)


def _first(folder: Path, *candidates: str) -> Path | None:
    return next((folder / c for c in candidates if (folder / c).is_file()), None)


def _silverbox(folder: Path) -> Split:
    csv = _first(folder, "silverbox/SNLS80mV.csv", "SNLS80mV.csv")
    mat = _first(folder, "Silverbox/SilverboxFiles/SNLS80mV.mat", "SilverboxFiles/SNLS80mV.mat")
    if csv is not None:
        columns = _csv_columns(csv)
        u, y = columns["V1"], columns["V2"]
    elif mat is not None:
        out = _mat(mat)
        u, y = out["V1"][0], out["V2"][0]
    else:
        raise FileNotFoundError
    whole = Record(y=y, u=u, sampling_time=1 / 610.35, name="SNLS80mV")
    arrow = dataclasses.replace(whole[100:40575], name="test_arrow_full", init_window=50)
    no_extrapolation = dataclasses.replace(arrow[:32000], name="test_arrow_no_extrapolation")
    multisine = whole[40650:127400]
    cut = int(len(multisine) * 0.75)
    estimation = dataclasses.replace(multisine[:cut], name="estimation")
    test = dataclasses.replace(multisine[cut:], name="test_multisine", init_window=50)
    return Split("silverbox", [estimation], [test, arrow, no_extrapolation], "V")


F16_LEVELS = ((1, False), (2, True), (3, False), (4, True), (5, False), (6, True), (7, False))


def _f16(outputs: tuple[int, ...]) -> Callable[[Path], Split]:
    """The F-16 split with the accelerations `outputs` (0-based; the official form is (0,))."""

    def load(folder: Path) -> Split:
        estimation, tests = [], []
        for level, validation in F16_LEVELS:
            stem = f"F16Data_FullMSine_Level{level}{'_Validation' if validation else ''}"
            csv = _first(folder, f"f16/{stem}.csv", f"{stem}.csv")
            mat = _first(
                folder, f"F16/F16GVT_Files/BenchmarkData/{stem}.mat", f"F16GVT_Files/BenchmarkData/{stem}.mat"
            )
            if csv is not None:
                c = _csv_columns(csv)
                force, acc, fs = (
                    c["Force"],
                    np.stack([c[f"Acceleration{i + 1}"] for i in range(3)]),
                    c["Fs"][0],
                )
            elif mat is not None:
                out = _mat(mat)
                force, acc, fs = out["Force"][0], out["Acceleration"], out["Fs"][0, 0]
            else:
                raise FileNotFoundError
            y = np.stack([acc[i] for i in outputs], axis=-1)
            record = Record(
                y=y, u=force, sampling_time=1 / float(fs), name=stem, init_window=50 if validation else 0
            )
            (tests if validation else estimation).append(record)
        return Split("f16" if outputs == (0,) else "f16-3", estimation, tests, "m/s^2")

    return load


TANKS_FILES = (
    "Cascaded_Tanks/CascadedTanksFiles/dataBenchmark.mat",
    "CascadedTanksFiles/dataBenchmark.mat",
    "cascaded-tanks/dataBenchmark.csv",
    "Cascaded_Tanks/CascadedTanksFiles/dataBenchmark.csv",
    "CascadedTanksFiles/dataBenchmark.csv",
)


def _cascaded_tanks(folder: Path) -> Split:
    path = _first(folder, *TANKS_FILES)
    if path is None:
        raise FileNotFoundError
    if path.suffix == ".csv":  # the authors' CSV: columns uEst, uVal, yEst, yVal, Ts (one value)
        out = {k: v[:, None] for k, v in _csv_columns(path).items()}
    else:
        out = _mat(path)
    ts = float(out["Ts"][0, 0])
    est = Record(y=out["yEst"][:, 0], u=out["uEst"][:, 0], sampling_time=ts, name="estimation")
    test = Record(y=out["yVal"][:, 0], u=out["uVal"][:, 0], sampling_time=ts, name="test", init_window=5)
    return Split("cascaded-tanks", [est], [test], "V")


def _emps(folder: Path) -> Split:
    paths = [_first(folder, f"EMPS/{n}", n) for n in ("DATA_EMPS.mat", "DATA_EMPS_PULSES.mat")]
    if None in paths:
        raise FileNotFoundError
    records = []
    for path, name, window in zip(paths, ("estimation", "test"), (0, 20), strict=True):
        out = _mat(path)
        t = out["t"][:, 0]
        records.append(
            Record(
                y=out["qm"][:, 0],
                u=out["vir"][:, 0],
                sampling_time=float(t[1] - t[0]),
                name=name,
                init_window=window,
            )
        )
    return Split("emps", records[:1], records[1:], "m")


def _wiener_hammerstein(folder: Path) -> Split:
    mat = _first(folder, "WienerHammerBenchMark/WienerHammerBenchMark.mat", "WienerHammerBenchMark.mat")
    if mat is None:
        raise FileNotFoundError
    out = _mat(mat)
    whole = Record(
        y=out["yBenchMark"][:, 0], u=out["uBenchMark"][:, 0], sampling_time=1 / float(out["fs"][0, 0])
    )
    data = whole[5200:184000]
    est = dataclasses.replace(data[:100000], name="estimation")
    test = dataclasses.replace(data[100000:], name="test", init_window=50)
    return Split("wiener-hammerstein", [est], [test], "V")


def _ced(folder: Path) -> Split:
    mat = _first(folder, "CED/DATAUNIF.MAT", "DATAUNIF.MAT")
    if mat is None:
        raise FileNotFoundError
    out = _mat(mat)
    estimation, tests = [], []
    for level, (u, y) in (("low", ("u11", "z11")), ("high", ("u12", "z12"))):
        whole = Record(y=out[y][:, 0], u=out[u][:, 0], sampling_time=0.02)
        estimation.append(dataclasses.replace(whole[:400], name=f"estimation {level} amplitude"))
        tests.append(dataclasses.replace(whole[400:], name=f"test {level} amplitude", init_window=4))
    return Split("ced", estimation, tests, "-")


for _b in (
    Benchmark("silverbox", "Silverbox (electronic Duffing oscillator)", "V",
              ("silverbox/SNLS80mV.csv", "Silverbox/SilverboxFiles/SNLS80mV.mat"), _silverbox, "Silverbox",
              ("mV", 1e3)),
    Benchmark("f16", "F-16 ground vibration test (Acceleration1, the official output)", "m/s^2",
              ("f16/F16Data_FullMSine_Level{1..7}[_Validation].csv", "F16/F16GVT_Files/BenchmarkData/*.mat"),
              _f16((0,)), "F16"),
    Benchmark("f16-3", "F-16 ground vibration test, all three accelerations", "m/s^2",
              ("f16/F16Data_FullMSine_Level{1..7}[_Validation].csv", "F16/F16GVT_Files/BenchmarkData/*.mat"),
              _f16((0, 1, 2)), "F16"),
    Benchmark("cascaded-tanks", "Cascaded tanks", "V",
              TANKS_FILES[:1] + TANKS_FILES[2:3], _cascaded_tanks, "Cascaded_Tanks"),
    # EMPS in mm, as the field publishes it (the loader's submission example multiplies the RMSE by 1000)
    Benchmark("emps", "Electro-mechanical positioning system", "m",
              ("EMPS/DATA_EMPS.mat", "EMPS/DATA_EMPS_PULSES.mat"), _emps, "EMPS", ("mm", 1e3)),
    Benchmark("wiener-hammerstein", "Wiener-Hammerstein 2009", "V",
              ("WienerHammerBenchMark/WienerHammerBenchMark.mat",), _wiener_hammerstein,
              "WienerHammerBenchMark", ("mV", 1e3)),
    Benchmark("ced", "Coupled electric drives", "-", ("CED/DATAUNIF.MAT",), _ced, "CED"),
):  # fmt: skip
    BENCHMARKS.add(_b.name, _b)


# a file whose presence says a benchmark is there (either layout)
MARKERS = {
    "silverbox": ("silverbox/SNLS80mV.csv", "Silverbox/SilverboxFiles/SNLS80mV.mat"),
    "f16": (
        "f16/F16Data_FullMSine_Level1.csv",
        "F16/F16GVT_Files/BenchmarkData/F16Data_FullMSine_Level1.mat",
    ),
    "cascaded-tanks": TANKS_FILES,
    "emps": ("EMPS/DATA_EMPS.mat",),
    "wiener-hammerstein": ("WienerHammerBenchMark/WienerHammerBenchMark.mat",),
    "ced": ("CED/DATAUNIF.MAT",),
}
MARKERS["f16-3"] = MARKERS["f16"]


def data_dir(given: str | os.PathLike | None) -> Path | None:
    """The folder of benchmark files: `given`, else $MOP_BENCHMARK_DATA, else None (the official loader)."""
    where = given if given is not None else os.environ.get(ENV_VAR)
    if where is None:
        return None
    folder = Path(where)
    if not folder.is_dir():
        source = "--data-dir" if given is not None else f"${ENV_VAR}"
        raise MopError(f"{source} {folder} is not a folder; give the folder that holds the benchmark files")
    return folder


def _fetched(benchmark: Benchmark) -> Path:
    """The official loader's cache folder for `benchmark`, downloading the files there if needed."""
    try:
        import nonlinear_benchmarks
    except ImportError:
        raise MopError(
            f"benchmark {benchmark.name}: no --data-dir (or ${ENV_VAR}) and no official loader; put "
            f"{' and '.join(benchmark.files[:1])} under a folder and pass --data-dir, or "
            "`pip install mop[benchmarks]` to download"
        ) from None
    try:
        paths = getattr(nonlinear_benchmarks, benchmark.official)(data_file_locations=True)
    except Exception as e:
        raise MopError(f"benchmark {benchmark.name}: the official loader could not fetch it ({e})") from None
    first = Path(paths if isinstance(paths, str) else paths[0])
    return first.parent


def load_benchmark(name: str, folder: str | os.PathLike | None = None) -> Split:
    """The official split of benchmark `name`, from `folder` (see data_dir) or the official loader."""
    benchmark = BENCHMARKS.get(name)
    where = data_dir(folder)
    if where is None:
        where = _fetched(benchmark)
    try:
        return benchmark.load(where)
    except FileNotFoundError:
        raise MopError(
            f"benchmark {name}: its files are not in {where}; put {' (or '.join(benchmark.files)}"
            f"{')' if len(benchmark.files) > 1 else ''} there"
        ) from None


def present(folder: str | os.PathLike | None) -> list[str]:
    """The benchmarks whose files are in `folder` (or $MOP_BENCHMARK_DATA)."""
    where = data_dir(folder)
    if where is None:
        return []
    return [name for name in BENCHMARKS.names() if any((where / f).is_file() for f in MARKERS[name])]
