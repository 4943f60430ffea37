"""Records as identification data comes: one long record split in time, an estimation and a validation
record (--val), the summary line, and `mop train`'s defaults (preset rule, experiment files, the ARX feature
on records with inputs, the plan line before the first step)."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from mop.cli import main
from mop.config import DataConfig, RunConfig, to_dict
from mop.experiments.presets import PRESETS
from mop.recipe.budget import MIN_STEPS
from mop.recipe.layers import training_config
from mop.recipe.plan import RECORDS_BODY
from mop.recipe.records import RECORDED_MODEL
from mop.record import Record
from mop.train.auto import MIXTURE_SIZE, STEP_COST, steps_for
from mop.train.estimate import duration
from mop.train.records import choose_split, read_recorded

pytestmark = pytest.mark.usefixtures("one_thread")

TINY = [
    "model.num_layers=1",
    "model.width=16",
    "model.num_heads=2",
    "model.context=8",
    "train.horizon=8",
    "train.batch_size=8",
    "train.steps=4",
    "train.log_every=2",
    "train.checkpoint_every=2",
    "train.device=cpu",
]


def write_record(path: Path, lengths=(200,), inputs: bool = True, seed: int = 0) -> Path:
    """CSV records: y_t = step index (so a window's steps identify themselves) plus the record's number
    * 1000; u a seeded random input."""
    rng = np.random.default_rng(seed)
    lines = ["trajectory,t,y0" + (",u0" if inputs else "")]
    for i, n in enumerate(lengths):
        for t in range(n):
            lines.append(f"r{i},{t},{1000 * i + t}" + (f",{rng.normal():.6f}" if inputs else ""))
    path.write_text("\n".join(lines) + "\n")
    return path


def test_auto_split_is_by_trajectory_where_possible_else_in_time():
    assert choose_split("auto", 30, 0.1) == "trajectory"
    assert choose_split("auto", 5, 0.2) == "trajectory"  # one held out, four left: as before
    assert choose_split("auto", 1, 0.1) == "time"
    assert choose_split("auto", 2, 0.1) == "time"  # round(0.2) = 0 held out
    assert choose_split("time", 30, 0.1) == "time"


def test_one_record_splits_in_time_and_no_window_crosses_the_cut(tmp_path):
    path = write_record(tmp_path / "one.csv", lengths=(200,))
    rec = read_recorded(DataConfig(path=str(path)))
    assert rec.split == "time"
    # the last ceil(0.1 * 200) = 20 steps validate, the first 180 train
    (train,), (val,) = rec.train_parts, rec.val_parts
    np.testing.assert_array_equal(train[:, 0], np.arange(180))
    np.testing.assert_array_equal(val[:, 0], np.arange(180, 200))
    stats = rec.fit()  # the training part only: mean of 0..179
    assert stats["y_mean"] == [89.5] and stats["y_std"] == [pytest.approx(np.arange(180).std())]
    cfg = DataConfig(path=str(path), **stats)
    windows = rec.windows(cfg, 8, torch.device("cpu"))
    assert windows.starts.shape[0] == 180 - 8  # every window of 9 steps inside 0..179
    g = torch.Generator().manual_seed(0)
    inputs, targets = windows.sample(500, g)
    steps = torch.cat([inputs[:, :1, 0], targets[..., 0]], 1).double() * stats["y_std"][0] + 89.5
    assert steps.max() < 179.5 and torch.allclose(steps.diff(dim=1), torch.ones(1, dtype=torch.float64))
    vin, vtarget = rec.validation(cfg, 8, torch.device("cpu"))
    assert vin.shape == (20 - 8, 8, 2)  # every window of 9 steps inside 180..199
    first = vin[:, 0, 0].double() * stats["y_std"][0] + 89.5
    assert first.min() > 179.5 and first.max() < 191.5 + 1e-3


def test_time_split_rounds_the_validation_length_up_as_record_split_does(tmp_path):
    # 0.1 * 203 = 20.3 and 0.1 * 57 = 5.7: floor (20, 5), round (20, 6) and ceil (21, 6) all differ
    path = write_record(tmp_path / "two.csv", lengths=(203, 57))
    rec = read_recorded(DataConfig(path=str(path), split="time", validation_fraction=0.1))
    assert [len(v) for v in rec.val_parts] == [21, 6]
    assert [len(t) for t in rec.train_parts] == [182, 51]
    for i, (train, val) in enumerate(zip(rec.train_parts, rec.val_parts, strict=True)):
        head, tail = Record(y=np.concatenate([train, val])[:, :1]).split(0.1)
        assert (len(head), len(tail)) == (len(train), len(val))
        np.testing.assert_array_equal(val[:, 0], 1000 * i + np.arange(len(train), len(train) + len(val)))


def test_a_validation_record_validates_and_all_of_data_trains(tmp_path):
    est = write_record(tmp_path / "est.csv", lengths=(100,))
    val = write_record(tmp_path / "val.csv", lengths=(30,), seed=1)
    rec = read_recorded(DataConfig(path=str(est), validation_path=str(val)))
    assert rec.split == "file" and len(rec.train_parts[0]) == 100 and len(rec.val_parts[0]) == 30
    assert "validation from --val (1 trajectory)" in rec.summary(8)
    assert "92 training / 22 validation windows of 9 steps" in rec.summary(8)
    wrong = write_record(tmp_path / "wrong.csv", lengths=(30,), inputs=False)
    with pytest.raises(Exception, match="has m=1 outputs and k=0 inputs, but .* has m=1, k=1"):
        read_recorded(DataConfig(path=str(est), validation_path=str(wrong)))


def test_validation_windows_are_thinned_evenly(tmp_path):
    path = write_record(tmp_path / "long.csv", lengths=(6000,))
    rec = read_recorded(DataConfig(path=str(path)))
    windows = rec.validation_windows(8)
    assert len(windows) == 256 and windows[0] == (0, 0) and windows[-1] == (0, 600 - 9)


def test_one_record_trains_through_the_cli_with_the_records_recipe(tmp_path, capsys):
    path = write_record(tmp_path / "one.csv", lengths=(300,))
    run = tmp_path / "run"
    linear = "model.rls_cubes=0"  # the ramp is simulated as well with cubed lags: keep the ARX's orders
    gpt = "model.arch=gpt"  # the transformer reading the recipe's ARX feature
    assert main(["train", "--data", str(path), "--out", str(run), "--no-progress", *TINY, linear, gpt]) == 0
    out = capsys.readouterr().out
    assert "1 trajectory (m=1, k=1), split in time: the last 30 of 300 steps validate;" in out
    assert "262 training / 22 validation windows of 9 steps" in out
    assert "with an intercept one-step prediction started from its least-squares fit on the training" in out
    assert "model: " in out and "parameters" in out and "4 steps of batch 8 x 8 on cpu: roughly" in out
    saved = json.loads((run / "config.json").read_text())
    small = PRESETS["small"].train
    assert saved["train"]["lr"] == small.lr and saved["train"]["lr_schedule"] == small.lr_schedule
    # the ARX orders are those `mop fit arx` chooses on the training part (the first 270 steps)
    part = tmp_path / "part.csv"
    part.write_text("\n".join(path.read_text().splitlines()[: 1 + 270]) + "\n")
    assert main(["fit", "arx", str(part), "--out", str(tmp_path / "arx")]) == 0
    orders = json.loads((tmp_path / "arx" / "fitted.json").read_text())["orders"]
    model = saved["model"]
    assert (model["rls_order"], model["arx_order"], model["rls_offset"]) == (orders["p"], orders["q"], True)
    assert len(model["rls_prior"]) == orders["p"] + orders["q"] + 1  # the fitted coefficients, m = k = 1
    records = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    assert any(np.isfinite(r.get("val_loss", np.nan)) for r in records)


def test_training_config_layers(tmp_path):
    small, paper = PRESETS["small"], PRESETS["paper"]
    model = training_config(None, "small").model  # the preset's auto resolved on its (linear) family
    off = {"rls_order": 0, "rls_prior": "none", "rls_prior_cov": None}
    unresolved = dataclasses.replace(model, features="auto", **off)
    assert unresolved == small.model and model.rls_order > 0 and model.rls_prior == "none"  # output-only
    assert training_config(None, "paper").train == paper.train
    with_inputs = write_record(tmp_path / "u.csv", lengths=(60,))
    without = write_record(tmp_path / "y.csv", lengths=(60,), inputs=False)
    body = training_config(None, None, str(with_inputs))  # the recipe's own network, no feature
    assert body.model.rls_order == 0 and body.train.steps == MIN_STEPS
    named = {**RECORDS_BODY, "train.horizon": 53, "model.context": 53}  # 54 training steps of 60
    assert all(getattr(getattr(body, k.split(".")[0]), k.split(".")[1]) == v for k, v in named.items())
    recipe = training_config(None, None, str(with_inputs), overrides=["model.arch=gpt"])
    assert recipe.model.rls_prior == "fit" and recipe.model.rls_offset and recipe.train.steps == MIN_STEPS
    assert all(getattr(recipe.model, k.split(".")[1]) == v for k, v in RECORDED_MODEL.items())
    assert training_config(None, None, str(with_inputs), overrides=["train.steps=9"]).train.steps == 9
    preset_model = dataclasses.replace(small.model, features="given")  # auto on records: the keys as given
    assert training_config(None, "small", str(with_inputs)).model == preset_model  # --preset: its own model
    assert training_config(None, None, str(without)).model.rls_order == 0  # no inputs: no ARX feature
    off = training_config(None, None, str(with_inputs), overrides=["model.rls_order=0"])
    assert off.model.rls_order == 0 and off.model.arx_order == 0  # a named feature key: no recipe at all
    toml = Path(__file__).resolve().parents[1] / "examples" / "rlc_circuit.toml"
    rlc = training_config(str(toml), "smoke")
    assert rlc.system.family == "rlc-circuit" and rlc.train.steps == PRESETS["smoke"].train.steps
    small = training_config(str(toml), "small")  # the small preset's model.features=auto, resolved
    assert small.model.features == "given" and small.model.arx_order > 0
    assert len(small.model.rls_prior_weights) == MIXTURE_SIZE  # rlc-circuit takes the mixture prior
    assert small.train.steps == steps_for(PRESETS["small"].train.steps, STEP_COST["mixture"])
    named = training_config(None, "small", overrides=["model.rls_order=3"])  # a named key: auto is off
    assert (named.model.features, named.model.rls_order, named.train.steps) == ("given", 3, 2500)
    quad = training_config(None, "small", overrides=["system.family=quadrotor", "train.steps=700"])
    assert quad.model.arx_order > 0 and quad.train.steps == 700  # auto on the family given; steps as given
    cfg = tmp_path / "c.json"
    cfg.write_text(json.dumps({"train": {"steps": 7}}))
    assert training_config(str(cfg)).train.steps == 7
    with pytest.raises(Exception, match="it fixes the model and training; drop --preset small"):
        training_config(str(cfg), "small")
    with pytest.raises(Exception, match="--val FILE is the validation record of --data FILE"):
        training_config(None, "small", None, str(with_inputs))


def test_rundirs_of_the_old_split_keep_their_config(tmp_path):
    """New data keys at their defaults are left out of config.json, so earlier runs keep their hash."""
    config = RunConfig(data=DataConfig(path="x.csv"))
    assert "split" not in to_dict(config)["data"] and "validation_path" not in to_dict(config)["data"]


def test_duration_words():
    assert duration(40.2) == "40 s" and duration(200) == "3 min 20 s" and duration(7500) == "2 h 05 min"
