"""Validation by free-run simulation of the held-out tail (mop.train.data.validates_tails): a model that
simulates across a gap (model.forecast_mode = "gap") trained on a record split in time is validated, and kept
by train.keep_best, on the simulation of the record's last steps after the steps before them. Against
`mop predict RUN WINDOW.csv --simulate C` on that window, run by run; and the fine-tuning defaults of a class
model on a record (its feature started from the record's least-squares ARX)."""

import json

import numpy as np
import pytest

import mop.train as mt
from mop.cli import main
from mop.config import DataConfig, ModelConfig, RunConfig, SystemConfig, TrainConfig
from mop.recipe.finetune import FINE_TUNE_SIMULATE_AFTER
from mop.recipe.layers import training_config
from mop.train.data import validates_tails

pytestmark = pytest.mark.usefixtures("one_thread")

T, HORIZON, AFTER = 240, 40, 10  # record y_0..y_T; the last ceil(0.1 (T + 1)) = 25 steps validate
CUT = HORIZON + 1 - 25  # 16 >= AFTER steps of the window before its held-out tail


def write_record(path, seed: int = 0) -> str:
    """A saturating first-order plant, y_{t+1} = y_t + 0.3 (tanh(2 u_t) - 0.5 y_t) + noise, as a CSV."""
    rng = np.random.default_rng(seed)
    u, y = rng.normal(size=T + 1), np.zeros(T + 1)
    for t in range(T):
        y[t + 1] = y[t] + 0.3 * (np.tanh(2 * u[t]) - 0.5 * y[t]) + 0.02 * rng.normal()
    rows = [f"r,{t},{float(a)!r},{float(b)!r}" for t, (a, b) in enumerate(zip(y, u, strict=True))]
    path.write_text("trajectory,t,y0,u0\n" + "\n".join(rows) + "\n")
    return str(path)


def gap_model(**kw) -> ModelConfig:
    base = dict(num_layers=1, num_heads=2, width=16, context=HORIZON, observation_mask=True)
    return ModelConfig(**{**base, "forecast_mode": "gap", "record_norm": "causal", "rls_order": 2, **kw})


def gap_config(data: str, steps: int, keep_best: bool, val: str | None = None) -> RunConfig:
    train = TrainConfig(
        steps=steps,
        batch_size=4,
        lr=3e-2,
        lr_schedule="constant",
        warmup_steps=0,
        horizon=HORIZON,
        simulate_after=AFTER,
        log_every=2,
        checkpoint_every=2,
        device="cpu",
        compile="off",
        deterministic=True,
        keep_best=keep_best,
    )
    model = gap_model(arx_order=2, rls_offset=True)
    data_config = DataConfig(data, validation_path=val or "")
    return RunConfig(system=SystemConfig(family="lti-siso"), model=model, train=train, data=data_config)


def val_losses(run) -> dict[int, float]:
    lines = (run / "metrics.jsonl").read_text().splitlines()
    return {r["step"]: r["val_loss"] for r in map(json.loads, lines) if "val_loss" in r}


def tail_simulation_mse(run, record: str, tmp_path) -> float:
    """The record's last HORIZON + 1 steps as a file of their own, simulated by `mop predict --simulate
    CUT` (the model's gap simulation in the record's units), MSE in the run's normalised units."""
    lines = open(record).read().splitlines()[-(HORIZON + 1) :]
    rows = [f"r,{t},{line.split(',', 2)[2]}" for t, line in enumerate(lines)]  # steps 0..HORIZON
    window = tmp_path / "window.csv"
    window.write_text("trajectory,t,y0,u0\n" + "\n".join(rows) + "\n")
    out = tmp_path / f"sim-{run.name}.npz"
    assert main(["predict", str(run), str(window), "--simulate", str(CUT), "--out", str(out)]) == 0
    y = np.loadtxt(window, delimiter=",", skiprows=1, usecols=2)
    std = json.loads((run / "config.json").read_text())["data"]["y_std"][0]
    return float(np.mean((np.load(out)["ysim"][0, :, 0] - y[CUT:]) ** 2) / std**2)


def test_keep_best_keeps_the_weights_that_simulate_the_held_out_tail_best(tmp_path, capsys):
    """Runs of 0, 2, 4, 6 steps at a constant lr (each the start of the longer one): each logged
    validation loss is the MSE of the tail's simulation computed apart by `mop predict --simulate`, and the
    keep_best run keeps the step of the lowest."""
    record = write_record(tmp_path / "rec.csv")
    assert validates_tails(gap_config(record, 2, False))
    best = mt.train(gap_config(record, 6, True), tmp_path / "best", progress=False)
    logged = val_losses(best)
    assert sorted(logged) == [0, 2, 4, 6]
    kept = json.loads((best / "done.json").read_text())["kept"]
    independent = {}
    for steps in (2, 4, 6):
        run = mt.train(gap_config(record, steps, False), tmp_path / f"s{steps}", progress=False)
        independent[steps] = tail_simulation_mse(run, record, tmp_path)
        assert logged[steps] == pytest.approx(independent[steps], rel=1e-4)
    if kept > 0:  # the kept weights simulate as the run stopped there
        assert tail_simulation_mse(best, record, tmp_path) == pytest.approx(independent[kept], rel=1e-6)
    assert kept == min(logged, key=logged.get)
    assert len({round(v, 6) for v in independent.values()}) == 3  # the choice is not a tie
    capsys.readouterr()


def test_with_a_validation_record_the_loss_is_the_simulation_of_its_windows(tmp_path, capsys):
    """--val: the validation loss is the pooled MSE of every validation window (T - HORIZON + 1 of them,
    none thinned) simulated from step AFTER on, computed apart by `mop predict --simulate AFTER` on a file
    holding those windows as trajectories."""
    record, val = write_record(tmp_path / "rec.csv"), write_record(tmp_path / "val.csv", seed=1)
    config = gap_config(record, 2, False, val=val)
    assert validates_tails(config)
    run = mt.train(config, tmp_path / "run", progress=False)
    lines = open(val).read().splitlines()[1:]
    rows = [
        f"w{s},{t},{line.split(',', 2)[2]}"
        for s in range(T - HORIZON + 1)
        for t, line in enumerate(lines[s : s + HORIZON + 1])
    ]
    windows = tmp_path / "windows.csv"
    windows.write_text("trajectory,t,y0,u0\n" + "\n".join(rows) + "\n")
    out = tmp_path / "sim.npz"
    assert main(["predict", str(run), str(windows), "--simulate", str(AFTER), "--out", str(out)]) == 0
    y = np.loadtxt(windows, delimiter=",", skiprows=1, usecols=2).reshape(T - HORIZON + 1, HORIZON + 1)
    std = json.loads((run / "config.json").read_text())["data"]["y_std"][0]
    mse = float(np.mean((np.load(out)["ysim"][..., 0] - y[:, AFTER:]) ** 2) / std**2)
    assert val_losses(run)[2] == pytest.approx(mse, rel=1e-4)
    capsys.readouterr()


def class_source(tmp_path) -> str:
    """A tiny class model (record_norm, in-context ARX with P_0 = 1e4 I, gap simulation), 1 step."""
    train = TrainConfig(steps=1, batch_size=4, horizon=HORIZON, simulate_after=AFTER, num_source_systems=0)
    model = gap_model(arx_order=2, rls_offset=True, rls_p0=1e4)
    config = RunConfig(system=SystemConfig(family="lti-siso"), model=model, train=train)
    return str(mt.train(config, tmp_path / "class", progress=False))


def test_fine_tuning_a_class_model_on_a_record(tmp_path):
    """The feature starts from the record's least-squares ARX (rls_prior=fit, the trainer's fit_prior),
    the windows fit the held-out part (25 steps: 24 + 1, a named simulate_after scaled alike), with or
    without a validation record, and are validated on its simulation; an override of the prior keeps the
    source's feature."""
    src, record = class_source(tmp_path), write_record(tmp_path / "rec.csv")
    config = training_config(None, data=record, init=src)
    assert (config.model.rls_prior, config.model.rls_p0) == ("fit", 1.0)
    # the simulated tails start anywhere from step 1 (FINE_TUNE_SIMULATE_AFTER); a named start is scaled
    assert config.train.horizon == 24 and config.train.simulate_after == FINE_TUNE_SIMULATE_AFTER == 1
    named = training_config(None, data=record, init=src, overrides=[f"train.simulate_after={AFTER}"])
    assert named.train.simulate_after == round(AFTER * 24 / HORIZON) > 1
    assert validates_tails(config)
    # with a validation record the windows are the same (a tenth of the estimation record)
    with_val = training_config(None, data=record, val=write_record(tmp_path / "val.csv", 1), init=src)
    assert with_val.train.horizon == 24 and validates_tails(with_val)
    kept = training_config(None, data=record, init=src, overrides=['model.rls_prior="none"'])
    assert (kept.model.rls_prior, kept.model.rls_p0) == ("none", 1e4)
    ft = tmp_path / "ft"
    argv = ["train", "--data", record, "--init", src, "--out", str(ft), "--no-progress", "train.steps=2"]
    assert main(argv) == 0
    saved = json.loads((ft / "config.json").read_text())["model"]
    # a row per regressor of the orders read (`mop fit arx`'s on the record), and the intercept
    d = saved["rls_order"] + saved["arx_order"] + 1
    assert isinstance(saved["rls_prior"], list) and len(saved["rls_prior"]) == d
