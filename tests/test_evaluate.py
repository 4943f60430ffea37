"""mop.evaluate: per-system errors and the eval.json summary vs numpy on hand-built trajectories."""

import numpy as np
import pytest
import torch

from mop.errors import MopError
from mop.evaluate import evaluate, summarize, windows
from mop.systems.base import Trajectories


class ScaledPredictor:
    """yhat_t = scale * y_t + offset: errors known in closed form."""

    def __init__(self, name, scale, offset=0.0):
        self.name, self.scale, self.offset = name, scale, offset

    def predict(self, traj):
        return traj.y * self.scale + self.offset


def _traj(num_systems=40, horizon=30, output_dim=2, seed=0):
    g = torch.Generator().manual_seed(seed)
    y = torch.randn(num_systems, horizon + 1, output_dim, generator=g, dtype=torch.float64)
    return Trajectories(y=y, u=None, x=None, family="linear")


def test_evaluate_errors_match_numpy():
    traj = _traj()
    result = evaluate([ScaledPredictor("a", 0.5), ScaledPredictor("b", 1.0, 0.3)], traj, progress=False)
    y = traj.y.numpy()
    np.testing.assert_allclose(result["a"]["e"], np.linalg.norm(0.5 * y, axis=-1), rtol=1e-12)
    np.testing.assert_allclose(result["b"]["e"], np.full(y.shape[:2], 0.3 * np.sqrt(2)), rtol=1e-12)


def test_evaluate_rejects_wrong_shape():
    class Bad:
        name = "bad"

        def predict(self, traj):
            return traj.y[:, 1:]

    with pytest.raises(MopError, match="bad"):
        evaluate([Bad()], _traj(), progress=False)


def test_summary_schema_and_ratios():
    traj = _traj(horizon=50)
    result = evaluate([ScaledPredictor("mop", 0.5), ScaledPredictor("kalman", 0.25)], traj, progress=False)
    s = summarize(result, reference="kalman")
    assert s["num_systems"] == 40 and s["horizon"] == 50
    for name in ("mop", "kalman"):
        c = s["predictors"][name]
        assert len(c["error"]) == len(c["squared_error"]) == 51
        assert all(isinstance(v, float) for v in c["error"])
    # errors scale exactly: ||0.5 y - y||^2 / ||0.25 y - y||^2 = (0.5 / 0.75)^2 for every system and window
    for w, r in s["ratios_to_reference"]["ratios"]["mop"].items():
        assert r["ratio"] == pytest.approx(4 / 9) and r["low"] == pytest.approx(4 / 9), w
    e = np.linalg.norm(0.5 * traj.y.numpy(), axis=-1)
    assert s["predictors"]["mop"]["window_error"]["[1,10]"] == pytest.approx(e[:, 1:11].mean())
    assert set(windows(50)) == {"[1,10]", "[10,20)", "[20,51)", "all"}


def test_baselines_by_name():
    """The paper's baselines are registered predictors; each class registered directly declares the name
    it is registered under (make_predictor's own naming is not what is checked)."""
    from mop.predictors import PREDICTORS, make_predictor

    names = (
        "kalman",
        "kalman-system1",
        "kalman-colored",
        "rls",
        "rls-best",
        "n4sid-kf",
        "zero",
        "last",
        "ekf",
    )
    names += ("ekf-noclip", "ukf", "ukf-noclip", "pf", "pf-noclip")
    for name in names:
        entry = PREDICTORS.get(name)
        if isinstance(entry, type):  # a class (the -noclip variants are lambdas over another class)
            assert entry.name == name, f"{entry.__name__}.name is {entry.name!r}, registered as {name!r}"
    assert sum(isinstance(PREDICTORS.get(n), type) for n in names) >= 10
    with pytest.raises(MopError, match="unknown predictor 'nope'"):
        make_predictor("nope")
