"""n4sid-kf says where its fallback (RLS-AR(2), ARX(2, 2) with inputs) made the predictions: the per-step mask
model_used against the fallback's own predictions, and a MopWarning when the fallback made most of them."""

import warnings

import numpy as np
import pytest
import torch

from mop.cli import main
from mop.config import SystemConfig
from mop.errors import MopWarning
from mop.filters.arx import arx_predict
from mop.predictors import make_predictor
from mop.systems import generator, make_family


def linear_inputs(num, horizon, seed):
    config = SystemConfig(family="linear-inputs", state_dim=3, output_dim=1, input_dim=1)
    return make_family(config, torch.float64).generate(num, horizon, generator=generator(seed))


def test_the_mask_marks_exactly_the_steps_the_fallback_predicted():
    traj = linear_inputs(8, 80, 0)
    predictor = make_predictor("n4sid-kf")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", MopWarning)
        yhat = predictor.predict(traj)
    used = predictor.model_used  # (B, T+1)
    fallback = arx_predict(traj.y, traj.u, 2, 2)
    assert used.shape == yhat.shape[:2] and used.any() and (~used).any()
    torch.testing.assert_close(yhat[~used], fallback[~used], rtol=0, atol=0)
    assert ((yhat[used] - fallback[used]).abs().amax(-1) > 0).all()


def test_a_model_that_rarely_identifies_warns_and_one_that_does_not():
    traj = linear_inputs(4, 60, 1)
    with pytest.warns(MopWarning, match=r"ARX\(2, 2\) fallback made 100% of the predictions from t_0 = 80"):
        make_predictor("n4sid-kf", min_prefix=80).predict(traj)  # t_0 beyond the record: fallback throughout
    long = linear_inputs(4, 300, 2)
    with warnings.catch_warnings():
        warnings.simplefilter("error", MopWarning)
        predictor = make_predictor("n4sid-kf", order=3, every=10)
        predictor.predict(long)
    assert predictor.model_used[:, 100:].double().mean() > 0.5


def test_the_cli_prints_the_warning(tmp_path, capsys):
    rng = np.random.default_rng(0)
    path = tmp_path / "short.csv"
    rows = ["trajectory,t,y0,u0"] + [f"a,{t},{rng.normal():.6g},{rng.normal():.6g}" for t in range(15)]
    path.write_text("\n".join(rows) + "\n")
    assert main(["predict", "n4sid-kf", str(path), "--out", str(tmp_path / "p.csv")]) == 0
    assert "mop: warning: n4sid-kf: its ARX(2, 2) fallback made 100%" in capsys.readouterr().err
