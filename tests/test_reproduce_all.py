"""Every registered experiment end to end on a cut-down smoke preset: eval.json's schema, the report and
figures, and the experiment-specific results present and sane."""

import json
import math
import operator
import re
from pathlib import Path

import pytest

from mop import cli
from mop.experiments import EXPERIMENTS


def _reproduce(tmp_path, name: str, *extra: str) -> tuple[dict, str]:
    out = tmp_path / name
    assert cli.main(["reproduce", name, "--preset", "smoke", "--out", str(out), "--quiet", *extra]) == 0
    assert list(out.glob("*.png")) and list(out.glob("*.pdf")), "figures in PNG and PDF"
    return json.loads((out / "eval.json").read_text()), (out / "report.md").read_text()


COMPARE = {"<": operator.lt, "<=": operator.le, ">": operator.gt, ">=": operator.ge}


def expected_verdict(claim: dict) -> bool | None:
    """The claim's verdict recomputed from its value, op and threshold (None: info, or a NaN value)."""
    value, threshold, op = claim["value"], claim["threshold"], claim["op"]
    values = value if isinstance(value, list) else [value]
    if op == "info" or any(math.isnan(v) for v in values):
        return None
    if op == "between":
        return threshold[0] <= value <= threshold[1]
    if op == "contains":
        return value[0] <= threshold <= value[1]
    return COMPARE[op](value, threshold)


def _check_schema(data: dict, names: set[str]) -> None:
    T = data["horizon"]
    assert names <= set(data["predictors"])
    for curves in data["predictors"].values():
        assert len(curves["error"]) == len(curves["squared_error"]) == T + 1
        for e, e2 in zip(curves["error"], curves["squared_error"], strict=True):
            assert 0 <= e and e * e <= e2 + 1e-9  # Jensen: mean(e)^2 <= mean(e^2)


@pytest.mark.parametrize(
    "name, predictors",
    [
        ("colored-noise", {"mop", "kalman", "rls", "rls-best", "n4sid-kf"}),
        ("switching", {"mop", "kalman", "kalman-system1", "rls"}),
        ("quadrotor", {"mop", "ekf", "ukf", "pf"}),
        ("upper-triangular", {"mop", "kalman", "rls"}),
        ("linear-inputs", {"mop", "kalman", "arx", "n4sid-kf", "last"}),
    ],
)
def test_standard_experiments(tmp_path, tiny_smoke, name, predictors):
    data, report = _reproduce(tmp_path, name)
    assert data["experiment"] == name and data["preset"] == "smoke" and data["num_systems"] == 6
    _check_schema(data, predictors)
    assert data["horizon"] == (100 if name == "switching" else 50)
    assert "| mop |" in report and "MSE ratio" in report
    assert len(data["claims"]) >= 2
    for claim in data["claims"]:
        assert claim["holds"] == expected_verdict(claim), claim
    if name == "upper-triangular":
        powers = {k: v["matrix_power_ratio"] for k, v in data["conditions"].items()}
        assert len(powers["test"]) == len(powers["dense"]) == 50  # k = 0..49
        assert powers["test"][0] == powers["dense"][0] == 1.0  # ||A^0|| / rho^0
        assert (tmp_path / name / "fig4a_ratio.png").exists() and (
            tmp_path / name / "fig4b_powers.pdf"
        ).exists()
        assert set(data["conditions"]["dense"]["predictors"]) == {"mop", "kalman"}
    if name == "linear-inputs":  # the KF that uses B u is the best predictor; the report shows simulation
        curves = data["predictors"]
        late = {n: sum(c["squared_error"][20:]) for n, c in curves.items()}
        assert min(late, key=late.get) == "kalman" and "Free-run simulation" in report


def test_noise_shift_has_one_condition_per_level(tmp_path, tiny_smoke):
    data, report = _reproduce(tmp_path, "noise-shift")
    levels = [c["system"]["noise_var_w"] for c in data["settings"]["conditions"]]
    assert levels == [0.01, 0.05, 0.1, 0.2, 0.5]
    for entry in data["conditions"].values():
        _check_schema(entry, {"mop", "kalman", "rls"})
    kf = [v["predictors"]["kalman"]["window_error"]["all"] for v in data["conditions"].values()]
    assert kf == sorted(kf), "the KF's error grows with the test noise"
    assert (
        "test noise variance 0.5" in report and (tmp_path / "noise-shift" / "fig5_noise_shift.png").exists()
    )


def test_calibration_reports_coverage_and_nll(tmp_path, tiny_smoke):
    data, _ = _reproduce(tmp_path, "calibration")
    for family in ("linear", "colored-noise"):
        table = data["conditions"][family]["calibration"]
        assert set(table) == {"mop", "kalman"}
        for row in table.values():
            assert 0 <= row["coverage_50"] <= row["coverage_90"] <= row["coverage_95"] <= 1
            assert math.isfinite(row["nll"])
    assert (tmp_path / "calibration" / "calibration_colored-noise.png").exists()


def test_scaling_fits_a_slope_per_axis(tmp_path, tiny_smoke):
    data, report = _reproduce(tmp_path, "scaling", "train.steps=3")
    for axis in ("M", "T"):
        r = data["sweeps"][axis]
        assert len(r["values"]) == len(r["excess_mse"]) == 3
        assert math.isfinite(r["slope"]) and r["slope_stderr"] >= 0
        half = 12.706 * r["slope_stderr"]  # Student t quantile 0.975 with 1 dof (3 points, 2 parameters)
        assert r["slope_ci95"] == pytest.approx([r["slope"] - half, r["slope"] + half], rel=1e-3)
    assert "slope" in report and len(data["runs"]) == 6


def test_missing_data_sweeps_p_and_bursts(tmp_path, tiny_smoke):
    data, report = _reproduce(tmp_path, "missing-data")
    assert list(data["conditions"]) == ["p=0.00", "p=0.10", "p=0.30", "p=0.50", "bursts"]
    for entry in data["conditions"].values():
        _check_schema(entry, {"mop", "kalman", "rls", "last"})
    for entry in data["conditions"].values():  # errors over measured outputs: finite ratios everywhere
        ratios = entry["ratios_to_reference"]["ratios"]
        assert set(ratios) == {"mop", "rls", "last"} and all(
            math.isfinite(r["all"]["ratio"]) for r in ratios.values()
        )
    assert (tmp_path / "missing-data" / "missing-data_ratio.png").exists()
    assert len(data["claims"]) == 5 and "p=0.30" in report
    runs = set(data["runs"].values())
    assert len(runs) == 1, "one model trained with drop-outs serves every condition"
    config = json.loads((Path(runs.pop()) / "config.json").read_text())
    assert config["model"]["observation_mask"] and config["train"]["missing_rate"] == 0.3


def test_every_experiment_is_covered():
    """Every registered experiment is run end to end by some test: `reproduce` with its name in tests/."""
    source = "\n".join(p.read_text() for p in Path(__file__).parent.glob("test_*.py"))
    run = set(re.findall(r'_reproduce\(tmp_path, "([\w-]+)"', source))
    run |= set(re.findall(r'\["reproduce", "([\w-]+)"', source))
    run |= set(re.findall(r'^        \("([\w-]+)", \{', source, flags=re.M))  # test_standard_experiments
    missing = sorted(set(EXPERIMENTS.names()) - run)
    assert not missing, f"no test reproduces {missing}"
