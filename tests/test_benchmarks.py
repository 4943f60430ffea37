"""mop.benchmarks: the official splits (against the official loader's definitions, written out here), both
file layouts, the protocol's scoring against a numpy recomputation, and `mop benchmark`'s bad inputs
and files."""

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.io import savemat

from mop.benchmarks import load_benchmark, present
from mop.benchmarks.protocol import run_test
from mop.cli import main
from mop.identify import fit
from mop.identify.narx_model import KIND as FEATURE_KIND
from mop.identify.store import FILE as FITTED_FILE
from mop.identify.store import load as load_fitted
from mop.predictors import make_predictor
from mop.record import Record, read_records
from mop.runs import load_config, load_predictor, with_reading

EXCERPTS = Path(__file__).parent / "data" / "benchmarks"
SILVERBOX_LENGTH = 131072


def synthetic_silverbox(folder: Path) -> Path:
    """SNLS80mV.csv at full length with V1 = sample index and V2 = -index, in the authors' CSV format."""
    index = np.arange(SILVERBOX_LENGTH, dtype=float)
    path = folder / "silverbox" / "SNLS80mV.csv"
    path.parent.mkdir(parents=True)
    rows = "\n".join(f"{a:.0f},{-a:.0f}," for a in index)
    path.write_text('"V1","V2",\n' + rows + "\n")
    return path


def test_silverbox_split_is_the_official_one(tmp_path):
    """The official loader: estimation = the first int(0.75 * 86750) samples of [40650:127400]; tests its
    rest, [100:40575] and the first 32000 of that; n = 50 for all three."""
    synthetic_silverbox(tmp_path)
    split = load_benchmark("silverbox", tmp_path)
    (est,) = split.estimation
    cut = int(0.75 * (127400 - 40650))
    np.testing.assert_array_equal(est.u[:, 0], np.arange(40650, 40650 + cut))
    np.testing.assert_array_equal(est.y[:, 0], -np.arange(40650, 40650 + cut))
    expected = {
        "test_multisine": (40650 + cut, 127400),
        "test_arrow_full": (100, 40575),
        "test_arrow_no_extrapolation": (100, 32100),
    }
    assert [t.name for t in split.tests] == list(expected)
    for test in split.tests:
        start, stop = expected[test.name]
        np.testing.assert_array_equal(test.u[:, 0], np.arange(start, stop))
        assert test.init_window == 50 and test.sampling_time == pytest.approx(1 / 610.35)
    assert est.init_window == 0


def test_silverbox_from_the_loaders_cache_layout_equals_the_csv_layout(tmp_path):
    synthetic_silverbox(tmp_path / "csv")
    index = np.arange(SILVERBOX_LENGTH, dtype=float)
    mat = tmp_path / "cache" / "Silverbox" / "SilverboxFiles" / "SNLS80mV.mat"
    mat.parent.mkdir(parents=True)
    savemat(mat, {"V1": index[None], "V2": -index[None]})
    a, b = load_benchmark("silverbox", tmp_path / "csv"), load_benchmark("silverbox", tmp_path / "cache")
    for x, y in zip(a.estimation + a.tests, b.estimation + b.tests, strict=True):
        np.testing.assert_array_equal(x.y, y.y)
        np.testing.assert_array_equal(x.u, y.u)
        assert (x.name, x.init_window) == (y.name, y.init_window)


def test_f16_one_and_three_outputs_from_the_authors_files():
    """F-16 excerpts: estimation = the non-validation levels 1, 3, 5, 7, tests = 2, 4, 6 with n = 50; the
    official output is Acceleration1, f16-3 reads all three; input Force; Fs = 400 Hz."""
    one, three = load_benchmark("f16", EXCERPTS), load_benchmark("f16-3", EXCERPTS)
    assert [r.name[-6:] for r in one.estimation] == ["Level1", "Level3", "Level5", "Level7"]
    assert [r.name for r in one.tests] == [f"F16Data_FullMSine_Level{k}_Validation" for k in (2, 4, 6)]
    assert all(t.init_window == 50 for t in one.tests) and one.tests[0].sampling_time == 1 / 400
    raw = np.genfromtxt(EXCERPTS / "f16" / "F16Data_FullMSine_Level1.csv", delimiter=",", skip_header=1)
    np.testing.assert_array_equal(one.estimation[0].u[:, 0], raw[:, 0])
    np.testing.assert_array_equal(one.estimation[0].y[:, 0], raw[:, 2])
    np.testing.assert_array_equal(three.estimation[0].y, raw[:, 2:5])
    assert sorted(present(EXCERPTS)) == ["f16", "f16-3"]


def test_silverbox_excerpt_reads_as_the_authors_columns():
    folder = EXCERPTS / "silverbox"
    raw = np.genfromtxt(folder / "SNLS80mV_first3000.csv", delimiter=",", skip_header=1)
    assert raw.shape == (3000, 3) and np.abs(raw[:, 0]).max() < 0.2 and np.abs(raw[:, 1]).max() < 0.3


def test_the_protocol_scores_y_after_n_against_numpy():
    """`last` simulates y_{n-1} held constant: RMSE = sqrt(mean_t>=n (y_t - y_{n-1})^2)."""
    rng = np.random.default_rng(0)
    y, u = rng.normal(size=(300, 2)), rng.normal(size=(300, 1))
    test = Record(y=y, u=u, name="t", init_window=40)
    score = run_test(make_predictor("last"), test)
    assert score.diverged_at is None
    assert score.rmse == pytest.approx(
        np.sqrt(np.mean((y[40:] - y[39]) ** 2)), rel=1e-6
    )  # predictors compute in float32


def own_records(tmp_path, steps=600, seed=0):
    rng = np.random.default_rng(seed)
    u = rng.normal(size=steps)
    y = np.zeros(steps)
    for t in range(2, steps):
        y[t] = 1.5 * y[t - 1] - 0.7 * y[t - 2] + u[t - 1] + 0.02 * rng.normal()
    for name, part in (("est", slice(0, 400)), ("val", slice(400, steps))):
        rows = "\n".join(f"{a:.10g},{b:.10g}" for a, b in zip(y[part], u[part], strict=True))
        (tmp_path / f"{name}.csv").write_text("y0,u0\n" + rows + "\n")
    return tmp_path / "est.csv", tmp_path / "val.csv"


def test_own_records_run_the_protocol_and_write_named_files(tmp_path, capsys):
    est, val = own_records(tmp_path)
    out = tmp_path / "out"
    argv = ["benchmark", "--est", str(est), "--test", str(val), "--init-window", "20"]
    assert main([*argv, "--predictors", "arx,n4sid", "--out", str(out), "--quiet"]) == 0
    results = json.loads((out / "results.json").read_text())
    scores = results["est"]["val"]
    assert set(scores) == {"arx", "n4sid"} and all(s["diverged_at"] is None for s in scores.values())
    written = np.genfromtxt(out / "est" / "val_arx.csv", delimiter=",", names=True)
    rmse = np.sqrt(np.mean((written["y0"] - written["ysim0"]) ** 2))
    assert written["t"][0] == 20 and rmse == pytest.approx(scores["arx"]["rmse"], rel=1e-5)
    assert (out / "est" / "val.png").is_file() and "| val |" in (out / "report.md").read_text()


def test_a_shipped_class_model_runs_in_context(tmp_path):
    """pretrained:lti-siso reads the estimation record as context (mop.incontext) and is scored alike."""
    est, val = own_records(tmp_path)
    out = tmp_path / "out"
    argv = ["benchmark", "--est", str(est), "--test", str(val), "--init-window", "20", "--out", str(out)]
    assert main([*argv, "--predictors", "arx,pretrained:lti-siso", "--quiet"]) == 0
    scores = json.loads((out / "results.json").read_text())["est"]["val"]
    written = np.genfromtxt(out / "est" / "val_pretrained-lti-siso.csv", delimiter=",", names=True)
    rmse = np.sqrt(np.mean((written["y0"] - written["ysim0"]) ** 2))
    assert rmse == pytest.approx(scores["pretrained:lti-siso"]["rmse"], rel=1e-5)


def test_a_shipped_model_of_other_widths_is_refused_before_any_fit(tmp_path, capsys):
    """pretrained:lti-mimo (three outputs) on a one-output record: one line naming the models that fit,
    before the ARX listed first is fitted, and nothing written."""
    est, val = own_records(tmp_path)
    out = tmp_path / "out"
    argv = ["benchmark", "--est", str(est), "--test", str(val), "--out", str(out), "--quiet"]
    assert main([*argv, "--predictors", "arx,pretrained:lti-mimo"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "pretrained:lti-mimo reads 3 output(s) and 1 input(s)" in err
    assert "pretrained:lti-siso" in err and not out.exists()


@pytest.mark.parametrize(
    "argv, words",
    [
        (["nosuch"], "unknown benchmark 'nosuch'"),
        (["silverbox"], "silverbox/SNLS80mV.csv"),  # an empty --data-dir: which files go where
        ([], "none found"),
        (["--est", "E.csv"], "both --est EST and --test TEST"),
        (["silverbox", "--predictors", "arx,lstm"], "unknown lstm"),
        (["silverbox", "--predictors", "pretrained:nosuch"], "nosuch"),
        (["--est", "E.csv", "--test", "T.csv", "--train", "train.steps"], "is not key=value"),
    ],
)
def test_bad_input_is_one_line_and_writes_nothing(tmp_path, capsys, argv, words):
    empty = tmp_path / "data"
    empty.mkdir()
    out = tmp_path / "out"
    assert main(["benchmark", *argv, "--data-dir", str(empty), "--out", str(out), "--quiet"]) != 0
    err = capsys.readouterr().err.strip()
    assert words in err and len(err.splitlines()) == 1 and "Traceback" not in err
    assert not out.exists()


def test_a_data_dir_that_is_not_a_folder_is_one_line(tmp_path, capsys):
    assert (
        main(["benchmark", "silverbox", "--data-dir", str(tmp_path / "nope"), "--out", str(tmp_path / "o")])
        != 0
    )
    assert "is not a folder" in capsys.readouterr().err


def test_a_diverging_model_is_reported_as_diverged(tmp_path):
    """An ARX made unstable on purpose: the protocol's score is inf with the step it diverged at."""
    est, val = own_records(tmp_path)
    (record,) = read_records(est)
    arx = fit("arx", [record.pair])
    unstable = dataclasses.replace(arx, model=dataclasses.replace(arx.model, A=1.3 * arx.model.A))
    (test,) = read_records(val)
    score = run_test(unstable, dataclasses.replace(test, init_window=20))
    assert math.isinf(score.rmse) and score.diverged_at >= 20


def cubic_plant_benchmark(tmp_path, monkeypatch, *train: str) -> tuple[dict, Path]:
    """`mop benchmark --predictors arx,mop` on a Duffing-like record (a cubic restoring force; 1200 steps
    estimate, 400 test) with a short training (20 steps) and `--train` overrides: (the test's scores, the
    run directory)."""
    import mop.recipe.budget as budget

    monkeypatch.setattr(budget, "MIN_STEPS", 20)  # a short training: the feature carries the result
    rng = np.random.default_rng(0)
    steps = 1600
    u = rng.normal(size=steps)
    y = np.zeros(steps)
    for t in range(1, steps - 1):
        y[t + 1] = 1.6 * y[t] - 0.8 * y[t - 1] - 0.1 * y[t] ** 3 + 0.1 * u[t]
    y = y + 0.002 * rng.normal(size=steps)
    for name, part in (("est", slice(0, 1200)), ("val", slice(1200, steps))):
        rows = "\n".join(f"{a:.10g},{b:.10g}" for a, b in zip(y[part], u[part], strict=True))
        (tmp_path / f"{name}.csv").write_text("y0,u0\n" + rows + "\n")
    out = tmp_path / "out"
    argv = ["benchmark", "--est", str(tmp_path / "est.csv"), "--test", str(tmp_path / "val.csv")]
    argv += [f"--train={key}" for key in train]
    assert main([*argv, "--predictors", "arx,mop", "--out", str(out), "--quiet", "--budget", "0.1"]) == 0
    return json.loads((out / "results.json").read_text())["est"]["val"], out / "est" / "mop" / "run"


def test_mop_on_a_cubic_plant_keeps_its_cubic_feature_and_scores_the_network_beside_it(tmp_path, monkeypatch):
    """The network without its feature's run (data.feature_input=none): the records recipe chooses cubed
    output lags for its least-squares feature, the held-out check keeps that cubic NARX over the barely
    trained network, and the run's free run simulates the unseen test at under half the fitted ARX's RMSE
    (observed about a tenth); the network the check did not keep is scored beside it ("mop:network"), at
    what the run's network simulates in the reading its check scored lowest; the report says what MOP is."""
    scores, run = cubic_plant_benchmark(tmp_path, monkeypatch, "data.feature_input=none")
    chosen = json.loads((run / "selection.json").read_text())
    assert chosen["kept"] == FEATURE_KIND
    assert scores["mop"]["rmse"] < 0.5 * scores["arx"]["rmse"]
    assert set(scores) == {"arx", "mop", "mop:network"}  # the feature is what the run keeps
    (test,) = read_records(tmp_path / "val.csv")
    own = {reading: by[0]["score"] for reading, by in chosen["network"].items()}  # one gain: 1
    network = load_predictor(run)
    with_reading(network, min(own, key=own.get))  # in the reading the check scored lowest
    network = run_test(network, dataclasses.replace(test, init_window=50)).rmse
    assert network == pytest.approx(scores["mop:network"]["rmse"], rel=1e-6)
    report = (run.parents[2] / "report.md").read_text()  # OUT/report.md
    assert (
        "the run keeps the fitted least-squares feature, NARX(p=" in report
        and "held-out simulation" in report
    )


def test_mop_reading_its_cubic_features_run_is_kept_below_that_feature(tmp_path, monkeypatch):
    """The default: the network reads the cubic NARX's free run. After the same 20 steps the check keeps
    the network, which simulates the unseen test below the feature alone (observed 0.55 of it: asserted
    below 0.8) and the fitted ARX; the feature is scored beside it ("mop:feature") as `mop predict
    RUN/feature` simulates it."""
    scores, run = cubic_plant_benchmark(tmp_path, monkeypatch)
    chosen = json.loads((run / "selection.json").read_text())
    assert chosen["kept"] == "network" and chosen["linear_orders"][FEATURE_KIND]["c"] >= 1
    assert set(scores) == {"arx", "mop", "mop:feature"}
    assert scores["mop"]["rmse"] < 0.8 * scores["mop:feature"]["rmse"] < scores["arx"]["rmse"]
    (test,) = read_records(tmp_path / "val.csv")
    alone = run_test(load_fitted(run / "feature"), dataclasses.replace(test, init_window=50)).rmse
    assert alone == pytest.approx(scores["mop:feature"]["rmse"], rel=1e-9)


@pytest.mark.parametrize("passes", [None, 1])
def test_the_report_says_whether_the_budget_bound_the_training(tmp_path, monkeypatch, passes):
    """The report names the steps MOP trained and whether the budget set them: 0.1 min buys 0.1 * 60 / 0.02
    steps of 50-step windows, proportionally fewer of longer ones (the reference CPU's nominal step); where
    the record allows fewer (here one pass over its windows, MAX_EPOCHS = 1) a larger budget trains the
    same and the line says so."""
    import mop.recipe.budget as budget

    if passes is not None:
        monkeypatch.setattr(budget, "MAX_EPOCHS", passes)
    _, run = cubic_plant_benchmark(tmp_path, monkeypatch)
    config = load_config(run)
    bought = int(0.1 * 60 / (0.02 * max(1.0, config.train.horizon / 50)))
    report = (run.parents[2] / "report.md").read_text()
    if passes is None:
        assert config.train.steps == bought
        size = f"{config.model.arch} {config.model.num_layers} x {config.model.width}"
        assert f"mop: trained {size}, {bought} steps, what the 0.1-min budget buys" in report
    else:
        assert 20 < config.train.steps < bought
        line = f"{config.train.steps} steps, fewer than the {bought} the 0.1-min budget buys"
        assert line in report and "a larger --budget trains the same" in report


def test_a_shipped_model_fine_tuned_on_the_estimation_part_is_scored_as_its_run(tmp_path):
    """finetune:lti-siso trains `mop train --data EST --init pretrained:lti-siso` (its run directory under
    OUT says so) and is scored by the protocol on that run's model: the run's fitted predictor, simulated
    from the test's first 20 outputs, gives the reported RMSE."""
    est, val = own_records(tmp_path)
    out = tmp_path / "out"
    argv = ["benchmark", "--est", str(est), "--test", str(val), "--init-window", "20", "--out", str(out)]
    assert main([*argv, "--predictors", "finetune:lti-siso", "--quiet"]) == 0
    score = json.loads((out / "results.json").read_text())["est"]["val"]["finetune:lti-siso"]["rmse"]
    run = out / "est" / "finetune-lti-siso" / "run"
    assert load_config(run).train.init == "pretrained:lti-siso"
    (test,) = read_records(val)
    fitted = load_fitted(run) if (run / FITTED_FILE).is_file() else load_predictor(run)
    again = run_test(fitted, dataclasses.replace(test, init_window=20)).rmse
    assert again == pytest.approx(score, rel=1e-6)
    assert "finetune:NAME: pretrained:NAME fine-tuned" in (out / "report.md").read_text()


def test_a_fine_tune_of_other_widths_is_refused_before_any_fit(tmp_path, capsys):
    """In context a one-output model reads a three-output record one output at a time; a fine-tune trains on
    the record as it is, so finetune:lti-siso on a three-output record is one line before any fit."""
    rng = np.random.default_rng(0)
    for name in ("est", "val"):
        rows = "\n".join(",".join(f"{v:.6g}" for v in rng.normal(size=4)) for _ in range(200))
        (tmp_path / f"{name}.csv").write_text("y0,y1,y2,u0\n" + rows + "\n")
    out = tmp_path / "out"
    argv = ["benchmark", "--est", str(tmp_path / "est.csv"), "--test", str(tmp_path / "val.csv")]
    assert main([*argv, "--out", str(out), "--quiet", "--predictors", "arx,finetune:lti-siso"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "finetune:lti-siso reads 1 output(s)" in err and not out.exists()


def test_train_keys_reach_mops_training_and_its_run(tmp_path):
    """`--train KEY=VALUE` trains MOP as `mop train --data EST KEY=VALUE` would: the run's config holds the
    keys (the results pages label such a row with them: tests/test_results_pages.py)."""
    est, val = own_records(tmp_path)
    out = tmp_path / "out"
    argv = ["benchmark", "--est", str(est), "--test", str(val), "--init-window", "20", "--out", str(out)]
    keys = [
        "train.steps=3",
        "train.simulate_after=10",
        "model.observation_mask=true",
        "model.forecast_mode=gap",
    ]
    assert main([*argv, "--predictors", "mop", "--quiet", *(a for k in keys for a in ("--train", k))]) == 0
    config = load_config(out / "est" / "mop" / "run")
    assert (
        config.train.steps == 3 and config.train.simulate_after == 10 and config.model.forecast_mode == "gap"
    )
