"""train.shrink_correction (mop.recipe.shrink): a fine-tuned class model's correction scaled by the gain whose
free-run simulation of the estimation record is best. Checked against the same fine-tune without it (the
training is deterministic, so the weights differ only by the gain), against `mop predict --simulate 0`'s own
path (mop.records) for every gain's RMSE, and the choice against the minimum."""

import json

import numpy as np
import pytest
import torch

from mop.checkpoint import load_model_weights
from mop.cli import main
from mop.config import RunConfig, from_dict
from mop.io import read_trajectories
from mop.models import build_model
from mop.models.predictor import LearnedPredictor, Normalization
from mop.recipe.layers import training_config
from mop.recipe.shrink import GAINS, SHRINK_FILE
from mop.recipe.training import train
from mop.records import scores, simulate_all

SOURCE = "pretrained:lti-siso"  # a class model trained for simulation (train.simulate_after > 0)


@pytest.fixture(autouse=True)
def _one_thread(one_thread):
    yield


def nearly_linear_record(path, T: int = 400, seed: int = 0) -> str:
    """A second-order plant with a mild saturation and output noise, driven by held random steps."""
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.uniform(-1, 1, size=T // 20 + 1), 20)[: T + 1]
    x = np.zeros((T + 1, 2))
    for t in range(T):
        x[t + 1, 0] = 1.5 * x[t, 0] - 0.7 * x[t, 1] + np.tanh(0.8 * u[t])
        x[t + 1, 1] = x[t, 0]
    y = x[:, 0] + 0.05 * rng.normal(size=T + 1) + 2.0
    np.savez(path, y=y[None, :, None], u=u[None, :, None])
    return str(path)


def fine_tune(tmp_path, data: str, name: str, *overrides: str, cli: bool = True) -> tuple[dict, RunConfig]:
    """The fine-tune of SOURCE on data: by `mop train` (cli), or by the recipe's training alone (the weights
    as trained: no held-out choice after it)."""
    out = tmp_path / name
    keys = ["train.steps=6", "train.checkpoint_every=3", *overrides]
    if cli:
        argv = ["train", "--data", data, "--init", SOURCE, "--out", str(out), "--no-progress"]
        assert main([*argv, *keys]) == 0
    else:
        train(training_config(None, data=data, init=SOURCE, overrides=keys), out, progress=False)
    config = from_dict(RunConfig, json.loads((out / "config.json").read_text()))
    model = build_model(config.model)
    load_model_weights(out / "model.safetensors", model)
    return {k: v.clone() for k, v in model.state_dict().items()}, config


def records_rmse(weights: dict, config: RunConfig, gain: float) -> float:
    """RMSE of `mop predict RUN data --simulate 0` (mop.records' path) with the read-out scaled by gain."""
    model = build_model(config.model)
    scaled = {k: gain * v if k.startswith("read_out.") else v for k, v in weights.items()}
    model.load_state_dict(scaled)
    d = config.data
    predictor = LearnedPredictor(
        model.eval(), normalization=Normalization.from_lists(d.y_mean, d.y_std, d.u_mean, d.u_std)
    )
    data = read_trajectories(d.path)[1]
    sims = simulate_all(predictor, data, 1)
    return scores([y[1:] for y, _ in data], sims).rmse


def test_a_fine_tune_keeps_the_gain_that_simulates_its_record_best(tmp_path, capsys):
    data = nearly_linear_record(tmp_path / "est.npz")
    plain, config = fine_tune(tmp_path, data, "plain", cli=False)
    shrunk, shrunk_config = fine_tune(tmp_path, data, "shrunk", "train.shrink_correction=true")
    assert shrunk_config.train.shrink_correction and not config.train.shrink_correction
    assert "correction: kept at gain" in capsys.readouterr().out
    choice = json.loads((tmp_path / "shrunk" / SHRINK_FILE).read_text())
    gain = choice["gain"]
    # every gain's RMSE is what mop predict's own simulation path gives for the trained weights scaled by it
    expected = [records_rmse(plain, config, g) for g in GAINS]
    np.testing.assert_allclose(choice["free_run_rmse"], expected, rtol=1e-5)
    assert choice["gains"] == list(GAINS) and gain == GAINS[int(np.argmin(expected))]
    # the shipped weights are the trained ones with the read-out scaled by the gain, nothing else
    for key, value in plain.items():
        want = gain * value if key.startswith("read_out.") else value
        torch.testing.assert_close(shrunk[key], want, rtol=1e-6, atol=1e-7)
    # so it never simulates its record worse than the model as trained or its feature alone (gain 0)
    assert records_rmse(shrunk, shrunk_config, 1.0) <= min(expected[0], expected[-1]) + 1e-9


def test_fine_tunes_choose_their_gain_on_held_out_data_unless_shrink_is_asked_for(tmp_path, capsys):
    """A fine-tune keeps the records recipe's held-out choice (selection.json: the gain whose simulation of
    the held-out tail is best, or the better fitted linear model); train.shrink_correction=true chooses on
    the whole record instead, and then no held-out choice is made."""
    data = nearly_linear_record(tmp_path / "est.npz")
    assert not training_config(None, data=data, init=SOURCE).train.shrink_correction
    fine_tune(tmp_path, data, "held")
    choice = json.loads((tmp_path / "held" / "selection.json").read_text())
    scored = [s["score"] for s in choice["network"][choice["reading"] or next(iter(choice["network"]))]]
    if choice["kept"] == "network":
        best_linear = min(v["score"] for v in choice["linear_models"].values())
        assert choice["gain"] == choice["gains"][int(np.argmin(scored))] and min(scored) <= best_linear
    else:
        assert choice["linear_models"][choice["kept"]]["score"] < min(scored)
    assert "held-out simulation" in capsys.readouterr().out
    fine_tune(tmp_path, data, "whole", "train.shrink_correction=true")
    assert (tmp_path / "whole" / SHRINK_FILE).is_file() and not (
        tmp_path / "whole" / "selection.json"
    ).exists()


def test_shrinking_a_model_without_a_feature_is_refused_in_one_line(tmp_path, capsys):
    data = nearly_linear_record(tmp_path / "est.npz")
    argv = ["train", "--data", data, "--out", str(tmp_path / "r"), "--no-progress", "model.rls_order=0"]
    assert main([*argv, "train.steps=2", "train.horizon=20", "train.shrink_correction=true"]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "train.shrink_correction=true" in err[0] and "model.rls_order > 0" in err[0]
    assert not (tmp_path / "r" / "model.safetensors").exists()
