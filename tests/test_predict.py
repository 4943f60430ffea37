import numpy as np
import pytest
import torch

from mop.cli import main
from mop.runs import load_model, load_predictor
from mop.systems.base import Trajectories
from tests.reference import read_long_csv, write_long_csv
from tests.reference_models import half_window_start


def explicit_window(model, y: np.ndarray, context: int) -> np.ndarray:
    """Independent of LearnedPredictor: yhat_{t+1} = last output of the model on y_s..y_t, s the start of
    mode "window"'s half-overlapping window (tests.reference_models.half_window_start)."""
    z = torch.tensor(y[None], dtype=torch.float32)
    out = np.zeros_like(y)
    with torch.no_grad():
        for t in range(len(y) - 1):
            out[t + 1] = model(z[:, half_window_start(t, context) : t + 1])[0, -1].numpy()
    return out


def test_predict_csv_matches_explicit_window_and_lengths_differ(tiny_run, tmp_path):
    rng = np.random.default_rng(0)
    ys = [rng.normal(size=(17, 2)), rng.normal(size=(7, 2))]  # 17 > context 10: windows 0, 5, 10
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


def _one_at_a_time(predictor, data, steps):
    """Each trajectory alone (no padding): predict, or the k-step forecast."""
    from mop.predictors import forecast

    out = []
    for y, u in data:
        traj = Trajectories(
            y=torch.tensor(y[None], dtype=torch.float32),
            u=None if u is None else torch.tensor(u[None], dtype=torch.float32),
        )
        out.append(
            (predictor.predict(traj) if steps is None else forecast(predictor, traj, steps))[0].numpy()
        )
    return out


@pytest.mark.parametrize("steps", [None, 4])
@pytest.mark.parametrize("name", ["rls", "rls-best", "n4sid-kf", "last", "mop"])
def test_unequal_lengths_in_padded_batches_equal_one_at_a_time(
    name, steps, tiny_run, monkeypatch, one_thread
):
    """Sorted, padded batches (two of them here) give each trajectory's own predictions: bit for bit for
    the classical predictors; for the learned model to float32 rounding (the batched matrix products differ
    in the last bit from one-row ones, as they do for equal lengths)."""
    from mop import records
    from mop.predictors import make_predictor

    monkeypatch.setattr(records, "BATCH_SIZE", 4)
    rng = np.random.default_rng(3)
    data = [(rng.normal(size=(length, 2)), None) for length in (25, 31, 12, 40, 25, 33, 18)]
    p = load_predictor(tiny_run) if name == "mop" else make_predictor(name)
    batched, alone = records.predict_all(p, data, steps), _one_at_a_time(p, data, steps)
    for (y, _), a, b in zip(data, batched, alone, strict=True):
        assert a.shape == b.shape and a.shape[0] == len(y)
        if name == "mop":
            np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-6)
        else:
            np.testing.assert_array_equal(a, b)


def test_default_outputs_are_named_after_the_predictor_and_hold_the_measured_output(tmp_path, capsys):
    """Two predictors on one record keep two files (DATA_<predictor>_pred.csv); a simulation's file holds
    the measured outputs beside the simulated ones, equal to the record's."""
    import csv

    rng = np.random.default_rng(0)
    u = rng.normal(size=300)
    y = np.zeros(300)
    for t in range(1, 300):
        y[t] = 0.8 * y[t - 1] + 0.5 * u[t - 1] + 0.01 * rng.normal()
    rec = tmp_path / "val.csv"
    rec.write_text("y0,u0\n" + "\n".join(f"{a:.6f},{b:.6f}" for a, b in zip(y, u, strict=True)) + "\n")
    assert main(["fit", "arx", str(rec), "--out", str(tmp_path / "arx_model")]) == 0
    assert main(["predict", str(tmp_path / "arx_model"), str(rec), "--simulate", "20"]) == 0
    assert main(["predict", "rls", str(rec)]) == 0
    capsys.readouterr()
    assert sorted(p.name for p in tmp_path.glob("val_*pred.csv")) == [
        "val_arx_model_pred.csv",
        "val_rls_pred.csv",
    ]
    with open(tmp_path / "val_arx_model_pred.csv") as f:
        rows = list(csv.DictReader(f))
    assert [int(r["t"]) for r in rows] == list(range(20, 300))
    np.testing.assert_allclose([float(r["y0"]) for r in rows], y[20:], atol=1e-6)
