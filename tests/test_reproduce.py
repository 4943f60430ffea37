"""End to end: `mop reproduce linear --preset smoke` through mop.cli.main, then reuse of the finished run."""

import json
from pathlib import Path

import pytest

from mop import cli


def test_reproduce_linear_smoke_and_reuse(tmp_path, tiny_smoke, capsys):
    out = tmp_path / "linear"
    assert cli.main(["reproduce", "linear", "--preset", "smoke", "--out", str(out), "--quiet"]) == 0
    assert str(out / "report.md") in capsys.readouterr().out
    data = json.loads((out / "eval.json").read_text())
    assert data["experiment"] == "linear" and data["preset"] == "smoke" and data["num_systems"] == 6
    T = data["horizon"]
    assert T == 50
    assert {"mop", "kalman", "rls", "rls-best", "n4sid-kf", "zero", "last"} <= set(data["predictors"])
    for c in data["predictors"].values():
        assert len(c["error"]) == len(c["squared_error"]) == T + 1
    report = (out / "report.md").read_text()
    assert "| mop |" in report and "| kalman |" in report and "MSE ratio" in report
    assert (out / "linear_error.png").stat().st_size > 0 and (out / "linear_error.pdf").stat().st_size > 0
    claims = {c["claim"]: c for c in data["claims"]}
    late = claims["MOP matches the KF after ~20 steps"]
    assert late["value"] == data["ratios_to_reference"]["ratios"]["mop"]["[20,51)"]["ratio"]
    assert late["holds"] == (late["value"] <= 1.05)

    (run_dir,) = data["runs"].values()
    assert Path(run_dir).parent == tmp_path / "runs"  # shared runs live beside the experiment directory
    weights = Path(run_dir) / "model.safetensors"
    stamp = weights.stat().st_mtime_ns
    assert cli.main(["reproduce", "linear", "--preset", "smoke", "--out", str(out), "--quiet"]) == 0
    assert weights.stat().st_mtime_ns == stamp  # the finished run was reused, not retrained
    again = json.loads((out / "eval.json").read_text())["predictors"]["mop"]
    assert again["error"] == data["predictors"]["mop"]["error"]  # same model, same seeded test systems

    # an override changes the training config, hence the run directory
    assert (
        cli.main(
            [
                "reproduce",
                "linear",
                "--preset",
                "smoke",
                "--out",
                str(out),
                "--quiet",
                "model.width=16",
                "train.horizon=30",
            ]
        )
        == 0
    )
    overridden = json.loads((out / "eval.json").read_text())
    (other,) = overridden["runs"].values()
    assert overridden["horizon"] == 30  # the test horizon follows the trained horizon
    assert other != run_dir


def test_reproduce_rejects_unknown_experiment(capsys):
    assert cli.main(["reproduce", "nope"]) == 2
    assert "unknown experiment 'nope'" in capsys.readouterr().err


def test_with_and_without_name_predictors_from_the_registry(tmp_path, capsys):
    """--with / --without PREDICTOR; --gru / --no-gru are generated from the GRU's skip_presets metadata.
    An unknown name or one given both ways stops before anything is written."""
    from mop.errors import MopError
    from mop.experiments.reproduce import choices as chosen

    def choices(args):
        return chosen(args.with_, args.without)

    def parse(*flags):
        return cli.build_parser("reproduce").parse_args(["reproduce", "linear", *flags])

    assert choices(parse()) == {}
    assert choices(parse("--with", "gru")) == choices(parse("--gru")) == {"gru": True}
    assert choices(parse("--no-gru", "--without", "rls")) == {"gru": False, "rls": False}
    with pytest.raises(MopError, match="both name gru"):
        choices(parse("--gru", "--without", "gru"))
    out = tmp_path / "linear"
    argv = ["reproduce", "linear", "--preset", "smoke", "--out", str(out), "--quiet", "--with", "nope"]
    assert cli.main(argv) == 2
    assert "unknown predictor 'nope'" in capsys.readouterr().err and not out.exists()
