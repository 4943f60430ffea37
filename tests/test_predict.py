import numpy as np
import torch

from mop.cli import main
from mop.runs import load_model, load_predictor
from mop.systems.base import Trajectories
from tests.reference import read_long_csv, write_long_csv


def explicit_window(model, y: np.ndarray, context: int) -> np.ndarray:
    """Independent of LearnedPredictor: yhat_t = last output of the model on y_{max(0,t-C)}..y_{t-1}."""
    z = torch.tensor(y[None], dtype=torch.float32)
    out = np.zeros_like(y)
    with torch.no_grad():
        for t in range(1, len(y)):
            out[t] = model(z[:, max(0, t - context) : t])[0, -1].numpy()
    return out


def test_predict_csv_matches_explicit_window_and_lengths_differ(tiny_run, tmp_path):
    rng = np.random.default_rng(0)
    ys = [rng.normal(size=(13, 2)), rng.normal(size=(7, 2))]  # 13 > context 10: the window slides
    write_long_csv(tmp_path / "d.csv", ys)
    assert main(["predict", str(tiny_run), str(tmp_path / "d.csv"), "--out", str(tmp_path / "p.csv")]) == 0
    pred = read_long_csv(tmp_path / "p.csv")
    model, cfg = load_model(tiny_run)
    for i, y in enumerate(ys):
        np.testing.assert_allclose(
            pred[f"r{i}"], explicit_window(model, y, cfg.context), rtol=1e-5, atol=1e-5
        )


def test_predict_stream_longer_than_context(tiny_run, tmp_path, capsys):
    y = np.random.default_rng(1).normal(size=(2, 31, 2)).astype(np.float32)  # T=30 > context 10
    np.savez(tmp_path / "d.npz", y=y)
    argv = ["predict", str(tiny_run), str(tmp_path / "d.npz"), "--stream", "--out", str(tmp_path / "p.npz")]
    assert main(argv) == 0
    yhat = np.load(tmp_path / "p.npz")["yhat"]
    ref = load_predictor(tiny_run, mode="stream").predict(Trajectories(y=torch.tensor(y))).numpy()
    np.testing.assert_allclose(yhat, ref, rtol=1e-5, atol=1e-6)
    rmse = np.sqrt(((y[:, 1:] - yhat[:, 1:]) ** 2).mean())
    assert f"{rmse:.4g}" in capsys.readouterr().out  # overall RMSE printed
