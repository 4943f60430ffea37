"""`mop train --data FILE`: split, normalisation, windows, equivariance to units, bad files, resume, CLI."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch

import mop.train as mt
from mop.checkpoint import load_tensors
from mop.cli import main
from mop.config import DataConfig, RunConfig, SystemConfig, apply_overrides, from_dict, to_dict
from mop.errors import MopError
from mop.runs import load_config, load_predictor
from mop.systems import make_family
from mop.systems.base import Trajectories
from mop.train.records import read_recorded, recorded_data
from tests.reference import sigint_during_step

TINY = [
    "model.num_layers=1",
    "model.width=16",
    "model.num_heads=2",
    "model.context=8",
    "train.horizon=8",
    "train.batch_size=8",
    "train.log_every=2",
    "train.checkpoint_every=2",
    "train.device=cpu",
    "train.compile=off",
    "train.deterministic=true",
]


pytestmark = pytest.mark.usefixtures("one_thread")


def data_config(path: Path, steps: int = 6, **data) -> RunConfig:
    config = apply_overrides(RunConfig(), [*TINY, f"train.steps={steps}"])
    return RunConfig(model=config.model, train=config.train, data=DataConfig(path=str(path), **data))


def write_linear(path: Path, num: int = 30, horizon: int = 12, inputs: bool = True, seed: int = 0) -> Path:
    """The linear family's trajectories (u: a seeded random input when `inputs`) as an .npz."""
    traj = make_family(SystemConfig(state_dim=3, output_dim=2)).generate(
        num, horizon, generator=torch.Generator().manual_seed(seed)
    )
    arrays = {"y": traj.y.numpy().astype(np.float64)}
    if inputs:
        arrays["u"] = np.random.default_rng(seed).normal(2.0, 3.0, (num, horizon + 1, 1))
    np.savez(path, **arrays)
    return path


def write_csv(path: Path, trajectories: list[np.ndarray]) -> Path:
    lines = ["trajectory,t,y0"]
    for i, y in enumerate(trajectories):
        lines += [f"r{i},{t},{float(v[0])!r}" for t, v in enumerate(y)]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_split_is_seeded_disjoint_and_sized(tmp_path):
    path = write_linear(tmp_path / "d.npz", num=40)
    a = read_recorded(DataConfig(path=str(path), validation_fraction=0.25, split_seed=3))
    b = read_recorded(DataConfig(path=str(path), validation_fraction=0.25, split_seed=3))
    c = read_recorded(DataConfig(path=str(path), validation_fraction=0.25, split_seed=4))
    assert np.array_equal(a.val_index, b.val_index) and np.array_equal(a.train_index, b.train_index)
    assert not np.array_equal(a.val_index, c.val_index)
    assert len(a.val_index) == 10 and len(a.train_index) == 30
    assert set(a.val_index).isdisjoint(a.train_index)
    assert set(a.val_index) | set(a.train_index) == set(range(40))


def test_normalisation_is_numpy_mean_std_of_training_split_only(tmp_path):
    path = write_linear(tmp_path / "d.npz", num=20)
    with np.load(path) as f:
        y, u = f["y"].copy(), f["u"].copy()
    split = read_recorded(DataConfig(path=str(path), validation_fraction=0.3, split_seed=1))
    y[split.val_index] += 100.0  # the validation split far off: must not move the statistics
    np.savez(path, y=y, u=u)
    config = mt.resolve_config(data_config(path, validation_fraction=0.3, split_seed=1))
    d, train = config.data, split.train_index
    np.testing.assert_allclose(d.y_mean, y[train].reshape(-1, 2).mean(0), rtol=1e-12)
    np.testing.assert_allclose(d.y_std, y[train].reshape(-1, 2).std(0), rtol=1e-12)
    np.testing.assert_allclose(d.u_mean, u[train].reshape(-1, 1).mean(0), rtol=1e-12)
    np.testing.assert_allclose(d.u_std, u[train].reshape(-1, 1).std(0), rtol=1e-12)
    assert max(d.y_mean) < 50  # would be ~30 if the validation split counted
    assert (config.model.input_dim, config.model.output_dim) == (3, 2)
    assert from_dict(RunConfig, json.loads(json.dumps(to_dict(config)))) == config


def test_runs_without_data_keep_their_config_json():
    assert "data" not in to_dict(RunConfig())
    assert from_dict(RunConfig, to_dict(RunConfig())) == RunConfig()
    with pytest.raises(MopError, match="--data"):
        apply_overrides(RunConfig(), ["data.split_seed=2"])


def test_variable_lengths_are_windowed_and_short_ones_skipped(tmp_path):
    lengths = [5, 12, 20, 9, 30, 6]  # outputs per trajectory; horizon 8 needs 9
    rng = np.random.default_rng(0)
    trajs = [rng.normal(size=(n, 1)) for n in lengths]
    path = write_csv(tmp_path / "v.csv", trajs)
    config = mt.resolve_config(data_config(path, validation_fraction=0.2, split_seed=0))
    rec = recorded_data(config.data)
    windows = rec.windows(config.data, 8, torch.device("cpu"))
    train_long = [i for i in rec.train_index if lengths[i] >= 9]
    assert windows.starts.shape[0] == sum(lengths[i] - 8 for i in train_long)
    assert "skipped" in rec.summary(8)
    g = torch.Generator().manual_seed(0)
    inputs, targets = windows.sample(400, g)  # (400, 8, 1), (400, 8, 1)
    mean, std = config.data.y_mean[0], config.data.y_std[0]
    seen = set()
    for z, y in zip(inputs.double(), targets.double(), strict=True):
        raw = np.concatenate([z[:1, 0].numpy(), y[:, 0].numpy()]) * std + mean  # the 9 steps in data units
        hits = [
            (i, s)
            for i in train_long
            for s in range(lengths[i] - 8)
            if np.allclose(trajs[i][s : s + 9, 0], raw, atol=1e-5)
        ]
        assert len(hits) == 1, "a sampled window is not one window of a training trajectory"
        seen.add(hits[0])
    assert len(seen) == windows.starts.shape[0]  # every valid window gets drawn


def test_same_seed_same_weights_and_resume_equals_uninterrupted(tmp_path, monkeypatch):
    path = write_linear(tmp_path / "d.npz")
    config = data_config(path)
    a = mt.train(config, tmp_path / "a", progress=False)
    b = mt.train(config, tmp_path / "b", progress=False)
    restore = sigint_during_step(monkeypatch, 4)  # Ctrl-C arrives during the 4th step
    with pytest.raises(MopError, match="stopped by SIGINT at step 4"):
        mt.train(config, tmp_path / "c", progress=False)
    restore()
    c = mt.train(config, tmp_path / "c", progress=False)
    wa = load_tensors(a / "model.safetensors")[0]
    for run in (b, c):
        wr = load_tensors(run / "model.safetensors")[0]
        assert all(torch.equal(wa[k], wr[k]) for k in wa)


def _predict(run: Path, y: np.ndarray, u: np.ndarray) -> np.ndarray:
    traj = Trajectories(y=torch.tensor(y), u=torch.tensor(u))
    return load_predictor(run).predict(traj).numpy()


def test_predictions_come_back_in_user_units(tmp_path):
    """Scaling the file's y by 1000 and shifting by 5 (u by 0.01, -3) scales the predictions alike.

    Normalisation makes both trainings see the same numbers up to float64 rounding of (y - mean) / std, which
    the float32 cast hides, so the weights come out equal and the predictions differ only by the float64
    rescaling: tolerance 1e-6 relative to 1000 max|y| (observed 9e-14 absolute, 3e-17 relative).
    """
    path = write_linear(tmp_path / "d.npz", num=30)
    with np.load(path) as f:
        y, u = f["y"], f["u"]
    scaled = tmp_path / "scaled.npz"
    np.savez(scaled, y=1000 * y + 5, u=0.01 * u - 3)
    run = mt.train(data_config(path, steps=8), tmp_path / "raw", progress=False)
    run_s = mt.train(data_config(scaled, steps=8), tmp_path / "scaled", progress=False)
    test = write_linear(tmp_path / "test.npz", num=5, horizon=15, seed=9)  # longer than the context
    with np.load(test) as f:
        ty, tu = f["y"], f["u"]
    p = _predict(run, ty, tu)  # (5, 16, 2)
    p_s = _predict(run_s, 1000 * ty + 5, 0.01 * tu - 3)
    np.testing.assert_allclose(p_s, 1000 * p + 5, atol=1e-6 * 1000 * np.abs(ty).max())
    assert np.abs(p[:, 1:]).max() > 0.05  # not trivially zero
    np.testing.assert_allclose(p[:, 0], np.broadcast_to(load_config(run).data.y_mean, (5, 2)))
    # and the scaled run really predicts in the scaled units, not normalised ones
    assert abs(p_s[:, 1:].mean() - 5) < 1000 * np.abs(ty).max()
    assert np.abs(p_s[:, 1:] - (1000 * ty[:, 1:] + 5)).mean() < 1000 * np.abs(ty[:, 1:]).mean() * 2


def test_linear_family_file_trains_through_the_cli(tmp_path, capsys):
    """The linear family written by `mop simulate` trains through --data; mop predict reads raw data."""
    data = tmp_path / "lin.npz"
    argv = ["simulate", "linear", "--systems", "24", "--horizon", "10", "--out", str(data)]
    assert main([*argv, "state_dim=3", "output_dim=2"]) == 0
    run = tmp_path / "run"
    common = ["--out", str(run), "--no-progress", *TINY, "train.steps=4"]
    assert main(["train", "--data", str(data), *common, "data.validation_fraction=0.25"]) == 0
    out = capsys.readouterr().out
    assert "18 training / 6 validation" in out
    records = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    val = [r["val_loss"] for r in records if "val_loss" in r]
    assert val and all(np.isfinite(val))
    saved = json.loads((run / "config.json").read_text())
    assert saved["data"]["path"] == str(data) and len(saved["data"]["y_std"]) == 2
    assert saved["model"]["input_dim"] == 2 and saved["model"]["output_dim"] == 2
    assert main(["train", "--data", str(data), *common, "data.validation_fraction=0.25"]) == 0  # reused
    pred = tmp_path / "pred.npz"
    assert main(["predict", str(run), str(data), "--out", str(pred)]) == 0
    with np.load(pred) as f, np.load(data) as d:
        assert f["yhat"].shape == d["y"].shape and np.isfinite(f["yhat"]).all()


def _bad_files(tmp: Path) -> dict[str, tuple[Path, str]]:
    y = np.random.default_rng(0).normal(size=(6, 12, 2))
    files = {}
    nan = y.copy()
    nan[2, 3, 1] = np.nan
    np.savez(tmp / "nan.npz", y=nan)
    files["nan"] = (tmp / "nan.npz", "has 1 missing outputs (NaN / empty cells); train a model that reads")
    inf = y.copy()
    inf[2, 3, 1] = np.inf
    np.savez(tmp / "inf.npz", y=inf)
    files["inf"] = (tmp / "inf.npz", "y holds Inf")
    np.savez(tmp / "huge.npz", y=y * 1e13)  # beyond mop.io.MAX_ABS: garbage, not units
    files["huge"] = (tmp / "huge.npz", "limit")
    np.savez(tmp / "u.npz", y=y, u=np.zeros((6, 11, 1)))
    files["u width"] = (tmp / "u.npz", "u has shape")
    np.savez(tmp / "short.npz", y=y[:, :5])
    files["too short"] = (tmp / "short.npz", "no training trajectory has")
    np.savez(tmp / "one.npz", y=y[:1])
    files["one short record"] = (tmp / "one.npz", "split in time, the longest validation part has 2 of 12")
    (tmp / "bad.csv").write_text("trajectory,t,y0\nr0,0,1.0\nr0,1\n")
    files["malformed csv"] = (tmp / "bad.csv", "columns")
    (tmp / "mixed.csv").write_text("trajectory,t,y0,u0\nr0,0,1.0,x\n")
    files["non-numeric csv"] = (tmp / "mixed.csv", "line 2, column u0: 'x' is not a number")
    files["missing"] = (tmp / "missing.npz", "does not exist")
    return files


def test_bad_files_give_one_line_errors(tmp_path, capsys):
    for name, (path, message) in _bad_files(tmp_path).items():
        code = main(["train", "--data", str(path), "--out", str(tmp_path / name), "--no-progress", *TINY])
        err = capsys.readouterr().err.strip()
        assert code == 2, name
        assert err.startswith("mop: error: ") and "\n" not in err and message in err, (name, err)
        assert not (tmp_path / name).exists(), name
