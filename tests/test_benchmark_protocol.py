"""The benchmarks' windows and splits against the official loader's source, transcribed by hand.

Every number below was read in GerbenBeintema/nonlinear_benchmarks, file nonlinear_benchmarks/benchmarks.py
(commit 0f8f7ac of its repository), not copied from mop:
- EMPS: test = DATA_EMPS_PULSES.mat, `test.state_initialization_window_length = 20`; y = qm, u = vir.
- CED: `train_val = datasets[0][:400], datasets[1][:400]`, `test = datasets[0][400:], datasets[1][400:]`,
  `state_initialization_window_length = 4` for both tests; (u11, z11) and (u12, z12).
- Cascaded_Tanks: uEst/yEst estimate, uVal/yVal test, `test.state_initialization_window_length = 5`.
- WienerHammerBenchMark: `sys_data = full_data[5200:184000]`, `train, test = sys_data[:100000],
  sys_data[100000:]`, window 50.
- Silverbox: `test_arrow_full = data2[100:40575]`, `test_arrow_no_extrapolation = test_arrow_full[:32000]`,
  `multisine = data2[40650:127400]`, `s = int(len(multisine)*0.75)`, window 50 for the three tests.
- F16: sets no window (mop's choice, 50, is stated in every report).
The PyPI release 1.0.1 of the loader still has 50 for the tanks and 10 for CED; mop follows the repository.
EMPS results are published in mm: the loader's submission_examples/EMPS.py reports 1000 * RMSE.
"""

import numpy as np
import pytest
from scipy.io import savemat

from mop.benchmarks import BENCHMARKS, load_benchmark, present

LOADER_WINDOWS = {  # benchmark: {test name: n}, from the loader's source (see the module docstring)
    "emps": {"test": 20},
    "ced": {"test low amplitude": 4, "test high amplitude": 4},
    "cascaded-tanks": {"test": 5},
    "wiener-hammerstein": {"test": 50},
    "silverbox": {"test_multisine": 50, "test_arrow_full": 50, "test_arrow_no_extrapolation": 50},
}


def tanks_files(folder, layout):
    """The tanks benchmark's file with u = index, y = -index (uEst 0..1023, uVal 1000..2023), Ts = 4."""
    est, val = np.arange(1024.0), 1000 + np.arange(1024.0)
    if layout == "mat":
        path = folder / "Cascaded_Tanks" / "CascadedTanksFiles" / "dataBenchmark.mat"
        path.parent.mkdir(parents=True)
        savemat(path, {"uEst": est[:, None], "yEst": -est[:, None], "uVal": val[:, None],
                       "yVal": -val[:, None], "Ts": np.array([[4.0]])})  # fmt: skip
    else:  # the authors' CSV: uEst,uVal,yEst,yVal,Ts with Ts given once
        path = folder / "cascaded-tanks" / "dataBenchmark.csv"
        path.parent.mkdir(parents=True)
        rows = [
            f"{a:g},{b:g},{-a:g},{-b:g},{'4' if i == 0 else ''}"
            for i, (a, b) in enumerate(zip(est, val, strict=True))
        ]
        path.write_text("uEst,uVal,yEst,yVal,Ts\n" + "\n".join(rows) + "\n")


def ced_file(folder):
    path = folder / "CED" / "DATAUNIF.MAT"
    path.parent.mkdir(parents=True)
    n = 500
    column = np.arange(n)[:, None] * 1.0
    savemat(path, {"u11": column, "z11": -column, "u12": 1000 + column, "z12": -1000 - column})


def emps_files(folder):
    (folder / "EMPS").mkdir()
    for name, start in (("DATA_EMPS.mat", 0), ("DATA_EMPS_PULSES.mat", 10000)):
        t = np.arange(300) * 1e-3
        savemat(folder / "EMPS" / name, {"t": t[:, None], "qm": -(start + np.arange(300))[:, None] * 1.0,
                                         "vir": (start + np.arange(300))[:, None] * 1.0,
                                         "qg": np.zeros((300, 1))})  # fmt: skip


def wh_file(folder):
    path = folder / "WienerHammerBenchMark" / "WienerHammerBenchMark.mat"
    path.parent.mkdir(parents=True)
    n = 188000
    savemat(path, {"uBenchMark": np.arange(n)[:, None] * 1.0, "yBenchMark": -np.arange(n)[:, None] * 1.0,
                   "fs": np.array([[51200.0]])})  # fmt: skip


@pytest.mark.parametrize("layout", ["mat", "csv"])
def test_cascaded_tanks_split_and_window_are_the_loaders(tmp_path, layout):
    tanks_files(tmp_path, layout)
    assert present(tmp_path) == ["cascaded-tanks"]
    split = load_benchmark("cascaded-tanks", tmp_path)
    (est,), (test,) = split.estimation, split.tests
    np.testing.assert_array_equal(est.u[:, 0], np.arange(1024.0))
    np.testing.assert_array_equal(test.y[:, 0], -(1000 + np.arange(1024.0)))
    assert {test.name: test.init_window} == LOADER_WINDOWS["cascaded-tanks"]
    assert test.sampling_time == 4.0 and est.init_window == 0


def test_ced_split_and_windows_are_the_loaders(tmp_path):
    ced_file(tmp_path)
    split = load_benchmark("ced", tmp_path)
    assert {t.name: t.init_window for t in split.tests} == LOADER_WINDOWS["ced"]
    low_est, high_est = split.estimation
    np.testing.assert_array_equal(low_est.u[:, 0], np.arange(400.0))
    np.testing.assert_array_equal(split.tests[1].u[:, 0], 1000 + np.arange(400, 500.0))


def test_emps_window_is_the_loaders_and_its_tables_are_in_mm(tmp_path):
    emps_files(tmp_path)
    split = load_benchmark("emps", tmp_path)
    assert {t.name: t.init_window for t in split.tests} == LOADER_WINDOWS["emps"]
    np.testing.assert_array_equal(split.tests[0].u[:, 0], 10000 + np.arange(300.0))
    assert BENCHMARKS.get("emps").shown_units() == ("mm", 1e3)


def test_wiener_hammerstein_split_is_the_loaders(tmp_path):
    wh_file(tmp_path)
    split = load_benchmark("wiener-hammerstein", tmp_path)
    (est,), (test,) = split.estimation, split.tests
    np.testing.assert_array_equal(est.u[[0, -1], 0], [5200, 5200 + 99999])
    np.testing.assert_array_equal(test.u[[0, -1], 0], [105200, 183999])
    assert {test.name: test.init_window} == LOADER_WINDOWS["wiener-hammerstein"]
