"""An experiment file on recorded data only: MOP trained with data.path (mop train --data), evaluated on a
held-out file of recordings beside the predictors that need no model; system-aware ones are skipped."""

import json

import numpy as np

from mop import cli
from mop.config import SystemConfig
from mop.systems import generator, make_family


def _record(path, num, seed):
    traj = make_family(SystemConfig(state_dim=3, output_dim=2)).generate(num, 30, generator=generator(seed))
    np.savez(path, y=traj.y.numpy())  # y only: recordings carry no system parameters
    return traj.y


def test_recorded_experiment_file(tmp_path, tiny_smoke):
    _record(tmp_path / "train.npz", 40, 0)
    held_out = _record(tmp_path / "held_out.npz", 12, 1)
    (tmp_path / "recorded.toml").write_text(
        'name = "recorded"\ntitle = "recordings only"\n'
        'predictors = ["mop", "kalman", "rls", "n4sid-kf", "last"]\nreference = "rls"\n'
        '[train]\n"data.path" = "train.npz"\n"train.horizon" = 20\n'
        '[[conditions]]\nname = "held-out"\ndata = "held_out.npz"\nhorizon = 25\n'
    )
    out = tmp_path / "out"
    argv = ["reproduce", str(tmp_path / "recorded.toml"), "--preset", "smoke", "--out", str(out), "--quiet"]
    assert cli.main(argv) == 0
    data = json.loads((out / "eval.json").read_text())
    assert set(data["predictors"]) == {"mop", "rls", "n4sid-kf", "last"}  # kalman needs the system: skipped
    assert data["num_systems"] == 12 and data["horizon"] == 25
    (run_dir,) = data["runs"].values()
    saved = json.loads((tmp_path / "runs" / run_dir.split("/")[-1] / "config.json").read_text())
    assert saved["data"]["path"] == str(tmp_path / "train.npz") and saved["data"]["y_mean"] is not None
    y = held_out.double()
    e_last = (y[:, :25] - y[:, 1:26]).norm(dim=-1).mean(0)  # last: yhat_t = y_{t-1}, t = 1..25
    np.testing.assert_allclose(data["predictors"]["last"]["error"][1:], e_last.numpy(), rtol=1e-6)
