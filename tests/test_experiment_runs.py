"""An experiment file's [runs] entry is what the report evaluates: a `mop fit` model named for a classical
predictor replaces it (the report's `arx` row is that fitted model, not the online ARX), and an entry that
no condition evaluates is refused in one line."""

import json

import numpy as np
import torch

from mop import cli
from mop.identify import load as load_fitted
from mop.systems.base import Trajectories


def _records(path, num, seed, steps=40):
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(num, steps, 1))
    y = np.zeros((num, steps, 1))
    for t in range(1, steps):
        y[:, t] = 0.7 * y[:, t - 1] + u[:, t - 1] + 0.05 * rng.normal(size=(num, 1))
    np.savez(path, y=y, u=u)
    return y, u


def _experiment(tmp_path, runs: str) -> list[str]:
    (tmp_path / "exp.toml").write_text(
        'name = "fitted"\ntitle = "a fitted ARX by name"\npredictors = ["arx", "last"]\nreference = "last"\n'
        '[train]\n"data.path" = "train.npz"\n'
        '[[conditions]]\nname = "held-out"\ndata = "held_out.npz"\nhorizon = 30\n' + runs
    )
    return [
        "reproduce",
        str(tmp_path / "exp.toml"),
        "--preset",
        "smoke",
        "--out",
        str(tmp_path / "out"),
        "--quiet",
    ]


def test_a_fitted_model_named_in_runs_is_the_reports_row(tmp_path):
    _records(tmp_path / "train.npz", 20, 0)
    y, u = _records(tmp_path / "held_out.npz", 10, 1)
    assert cli.main(["fit", "arx", str(tmp_path / "train.npz"), "--out", str(tmp_path / "arx_model")]) == 0
    assert cli.main(_experiment(tmp_path, '[runs]\narx = "arx_model"\n')) == 0
    data = json.loads((tmp_path / "out" / "eval.json").read_text())
    fitted = load_fitted(tmp_path / "arx_model")
    traj = Trajectories(y=torch.from_numpy(y[:, :31]), u=torch.from_numpy(u[:, :31]))
    e = (fitted.predict(traj).double() - traj.y).norm(dim=-1).mean(0).numpy()  # mean ||e_t|| over records
    np.testing.assert_allclose(data["predictors"]["arx"]["error"][1:], e[1:], rtol=1e-5)


def test_a_runs_entry_nothing_evaluates_is_refused(tmp_path, capsys):
    _records(tmp_path / "train.npz", 20, 0)
    _records(tmp_path / "held_out.npz", 10, 1)
    assert cli.main(["fit", "arx", str(tmp_path / "train.npz"), "--out", str(tmp_path / "arx_model")]) == 0
    capsys.readouterr()
    assert cli.main(_experiment(tmp_path, '[runs]\nn4sid = "arx_model"\n')) != 0
    err = capsys.readouterr().err.strip()
    assert "'n4sid', which no condition evaluates" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "out" / "eval.json").exists()


def test_the_report_describes_the_model_it_evaluated_not_the_preset(tmp_path, capsys):
    """`mop reproduce linear --pretrained`: the settings and the closing line give the shipped model's own
    features and steps (from its config.json), not those the preset would train."""
    from mop.runs import load_config
    from mop.train import describe_features

    out = tmp_path / "out"
    assert cli.main(["reproduce", "linear", "--pretrained", "--preset", "smoke", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    shipped = load_config("pretrained:linear")
    own = f"{describe_features(shipped.model)}, {shipped.train.steps} steps"
    data = json.loads((out / "eval.json").read_text())
    assert data["settings"]["features"] == own
    assert f"features {own}" in printed
    (described,) = data["settings"]["evaluated"].values()
    assert f"{shipped.train.steps}" in described and "pretrained:linear" in described
    assert "MOP against the yardstick" in (out / "report.md").read_text()
