"""`mop bench forecast`: one row per (predictor, T, K) with both times, a plot, one-line errors."""

import json

import pytest

from mop.cli import main


def test_bench_forecast_rows_and_plot(tmp_path, capsys, one_thread):
    argv = ["bench", "forecast", "--systems", "2", "--horizons", "6,8", "--steps", "1,3"]
    argv += ["--predictors", "mop,mop-direct,rls", "--plot", str(tmp_path / "f.png"), "--json"]
    assert main(argv) == 0
    rows = json.loads(capsys.readouterr().out)["rows"]
    assert [(r["predictor"], r["T"], r["K"]) for r in rows] == [
        (p, T, K) for p in ("mop", "mop-direct", "rls") for T in (6, 8) for K in (1, 3)
    ]
    assert all(r["predict_s"] > 0 and r["forecast_s"] > 0 for r in rows)
    assert (tmp_path / "f.png").stat().st_size > 0


@pytest.mark.parametrize(
    ("flag", "value"), [("--horizons", "a,b"), ("--steps", "0"), ("--predictors", "ekf")]
)
def test_bench_forecast_bad_flags_one_line(flag, value, capsys):
    assert main(["bench", "forecast", flag, value]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and flag in err[0]
