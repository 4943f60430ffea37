import csv

import numpy as np
import torch

from mop.cli import main
from mop.runs import load_predictor
from mop.systems.base import Trajectories


def _write_csv(path, ys):
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["trajectory", "t", "y0", "y1"])
        for i, y in enumerate(ys):
            for t, row in enumerate(y):
                w.writerow([f"r{i}", t, *row])


def _read_pred(path):
    out = {}
    with open(path) as f:
        for r in list(csv.reader(f))[1:]:
            out.setdefault(r[0], []).append([float(v) for v in r[2:]])
    return {k: np.array(v) for k, v in out.items()}


def test_predict_csv_matches_predictor_and_lengths_differ(tiny_run, tmp_path):
    rng = np.random.default_rng(0)
    ys = [rng.normal(size=(13, 2)), rng.normal(size=(7, 2))]
    _write_csv(tmp_path / "d.csv", ys)
    assert main(["predict", str(tiny_run), str(tmp_path / "d.csv"), "--out", str(tmp_path / "p.csv")]) == 0
    pred = _read_pred(tmp_path / "p.csv")
    predictor = load_predictor(tiny_run)
    for i, y in enumerate(ys):
        ref = predictor.predict(Trajectories(y=torch.tensor(y[None], dtype=torch.float32)))[0].numpy()
        np.testing.assert_allclose(pred[f"r{i}"], ref, rtol=1e-5, atol=1e-6)


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
