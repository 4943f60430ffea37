"""What a new user with a record meets: a bare name that means two models is refused, the model that ran is
named, time in seconds and columns in any order read as the same record, gaps after a simulation's context
are simulated and left out of its score, every simulation gets its figure, leakage is said, and mop.load
gives the estimators' face on a Record."""

import csv
import warnings

import numpy as np
import pytest
import torch

import mop
from mop.cli import main
from mop.errors import MopError, MopWarning
from mop.estimators import ARX
from mop.identify import load as load_fitted
from mop.identify.store import save
from mop.record import Record, read_records, write_records
from mop.systems.base import Trajectories


def plant(n, seed):
    """A lightly damped second-order plant with one input and a little output noise."""
    rng = np.random.default_rng(seed)
    u, y = rng.normal(size=n), np.zeros(n)
    for t in range(2, n):
        y[t] = 1.5 * y[t - 1] - 0.7 * y[t - 2] + 0.5 * u[t - 1]
    return Record(y=y + 0.01 * rng.normal(size=n), u=u)


@pytest.fixture
def records(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    write_records([Record(y=plant(400, 0).y, u=plant(400, 0).u, name="est")], tmp_path / "est.csv")
    write_records([Record(y=plant(200, 1).y, u=plant(200, 1).u, name="val")], tmp_path / "val.csv")
    return tmp_path


def one_line_error(capsys, argv):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("mop: error:") and "\n" not in err
    return err


def test_a_bare_name_that_is_a_folder_and_a_predictor_is_refused_and_each_form_names_what_ran(
    records, capsys
):
    assert main(["fit", "arx", "est.csv", "--out", "arx", "--max-order", "3"]) == 0
    capsys.readouterr()
    err = one_line_error(capsys, ["predict", "arx", "val.csv", "--simulate", "20"])
    assert "./arx" in err and "baseline:arx" in err
    assert main(["predict", "./arx", "val.csv", "--simulate", "20", "--out", "fitted.csv"]) == 0
    assert "fitted by `mop fit` in ./arx" in capsys.readouterr().out
    assert main(["predict", "baseline:arx", "val.csv", "--simulate", "20", "--out", "online.csv"]) == 0
    assert "registered online predictor arx" in capsys.readouterr().out
    fitted = np.genfromtxt("fitted.csv", delimiter=",", names=True)["ysim0"]
    y, u = plant(200, 1).y[:, 0], plant(200, 1).u[:, 0]
    traj = Trajectories(y=torch.from_numpy(y)[None, :, None], u=torch.from_numpy(u)[None, :, None])
    np.testing.assert_allclose(fitted, load_fitted("arx").simulate(traj, 20)[0, :, 0], atol=1e-5)


def test_time_in_seconds_and_any_column_order_read_as_the_steps(tmp_path):
    r = plant(50, 2)
    steps = tmp_path / "steps.csv"
    steps.write_text(
        "t,y0,u0\n"
        + "\n".join(
            f"{t},{float(a)!r},{float(b)!r}"
            for t, (a, b) in enumerate(zip(r.y[:, 0], r.u[:, 0], strict=True))
        )
    )
    seconds = tmp_path / "seconds.csv"  # MATLAB-like: u first, time in s from 12.5, rows shuffled
    order = np.random.default_rng(0).permutation(50)
    seconds.write_text(
        "u0,t,y0\n"
        + "\n".join(f"{float(r.u[i, 0])!r},{12.5 + 0.01 * i:.2f},{float(r.y[i, 0])!r}" for i in order)
    )
    a, b = read_records(steps)[0], read_records(seconds)[0]
    np.testing.assert_array_equal(a.y, b.y)
    np.testing.assert_array_equal(a.u, b.u)
    assert a.sampling_time is None and b.sampling_time == pytest.approx(0.01)
    uneven = tmp_path / "uneven.csv"
    uneven.write_text("t,y0\n0,1\n0.01,2\n0.03,3\n0.04,4\n")
    with pytest.raises(MopError, match="neither the steps 0..T nor uniform time in seconds"):
        read_records(uneven)


def test_outputs_missing_after_the_context_are_simulated_and_left_out_of_the_score(records, capsys):
    assert main(["fit", "arx", "est.csv", "--out", "model", "--max-order", "3"]) == 0
    val = read_records("val.csv")[0]
    gappy = val.y.copy()
    gappy[[60, 61, 150]] = np.nan
    write_records([Record(y=gappy, u=val.u, name="val")], records / "gaps.csv")
    capsys.readouterr()
    assert main(["predict", "model", "gaps.csv", "--simulate", "20", "--out", "gaps_sim.csv"]) == 0
    out = capsys.readouterr().out
    assert "3 step(s) after the context have missing outputs" in out
    written = np.genfromtxt("gaps_sim.csv", delimiter=",", names=True)
    complete = mop.load("model").simulate(val, init=20)[20:, 0]  # the simulation reads no output after 20
    np.testing.assert_allclose(written["ysim0"], complete, atol=1e-5)
    seen = ~np.isnan(gappy[20:, 0])
    rmse = np.sqrt(np.mean((val.y[20:, 0][seen] - complete[seen]) ** 2))
    row = next(line for line in out.splitlines() if line.split() and line.split()[0] == "overall")
    assert float(row.split()[4]) == pytest.approx(rmse, rel=1e-3)  # sim rmse over the measured steps
    assert not np.isnan(written["ysim0"]).any()


def test_every_simulation_gets_a_figure_and_one_csv_layout(records, capsys):
    assert main(["fit", "arx", "est.csv", "--out", "model", "--max-order", "3"]) == 0
    assert main(["predict", "model", "val.csv", "--simulate", "20", "--out", "sim.csv"]) == 0
    assert (records / "sim.png").is_file()
    argv = ["benchmark", "--est", "est.csv", "--test", "val.csv", "--init-window", "20", "--quiet"]
    assert main([*argv, "--predictors", "arx", "--out", "bench"]) == 0
    with open("sim.csv") as f, open(records / "bench" / "est" / "val_arx.csv") as g:
        assert next(csv.reader(f)) == next(csv.reader(g)) == ["trajectory", "t", "y0", "ysim0"]
    report = (records / "bench" / "report.md").read_text()
    assert report.startswith("# Your records") and "[]" not in report and "official" not in report


def test_scoring_the_records_a_model_was_fitted_on_is_said(records, capsys):
    assert main(["fit", "arx", "est.csv", "--out", "model", "--max-order", "3"]) == 0
    capsys.readouterr()
    assert main(["predict", "model", "est.csv", "--simulate", "20", "--out", "a.csv"]) == 0
    assert "these are the records model was fitted on" in capsys.readouterr().out
    assert main(["predict", "model", "val.csv", "--simulate", "20", "--out", "b.csv"]) == 0
    assert "fitted on" not in capsys.readouterr().out
    argv = ["benchmark", "--est", "est.csv", "--test", "est.csv", "--init-window", "20", "--quiet"]
    assert main([*argv, "--predictors", "arx", "--out", "leak"]) == 0
    assert "holds the estimation record" in (records / "leak" / "report.md").read_text()
    argv = ["benchmark", "--est", "est.csv", "--test", "val.csv", "--init-window", "20", "--quiet"]
    assert main([*argv, "--predictors", "arx", "--out", "clean"]) == 0
    assert "holds the estimation record" not in (records / "clean" / "report.md").read_text()


def test_mop_load_gives_the_estimators_face_on_a_record(records):
    est, val = read_records("est.csv")[0], read_records("val.csv")[0]
    fitted = ARX(na=2, nb=2).fit(est)
    save(fitted.predictor_, records / "model")
    loaded = mop.load("model")
    np.testing.assert_array_equal(loaded.simulate(val, init=20), fitted.simulate(val, init=20))
    np.testing.assert_array_equal(loaded.predict(val), fitted.predict(val))
    assert loaded.forecast(val, 5).shape == (len(val), 5, 1)
    traj = Trajectories(y=torch.from_numpy(val.y)[None], u=torch.from_numpy(val.u)[None])
    np.testing.assert_allclose(
        loaded.simulate(traj, 20)[0].numpy(), fitted.simulate(val, init=20)[20:], atol=1e-5
    )
    refit = mop.load("model").fit(val)  # the same kind and orders, fitted on the new record
    np.testing.assert_allclose(refit.simulate(est, init=20), ARX(na=2, nb=2).fit(val).simulate(est, init=20))
    with_context = mop.load("pretrained:lti-siso", context=est).simulate(val, init=20)
    assert with_context.shape == val.y.shape and np.isfinite(with_context[20:]).all()


def test_a_learned_model_trained_without_gaps_simulates_a_record_with_gaps_after_its_context(records):
    """pretrained:duffing-records reads no gaps (no observation mask); a simulation reads no output after
    its context, so gaps there change nothing."""
    val = read_records("val.csv")[0]
    gappy = val.y.copy()
    gappy[[60, 150]] = np.nan
    model = mop.load("pretrained:duffing-records")
    np.testing.assert_array_equal(
        model.simulate(Record(y=gappy, u=val.u), init=20), model.simulate(val, init=20)
    )
    write_records([Record(y=gappy, u=val.u, name="val")], records / "gaps.csv")
    assert (
        main(["predict", "pretrained:duffing-records", "gaps.csv", "--simulate", "20", "--out", "s.csv"]) == 0
    )
    np.testing.assert_allclose(
        np.genfromtxt("s.csv", delimiter=",", names=True)["ysim0"],
        model.simulate(val, init=20)[20:, 0],
        atol=1e-6,
    )


def test_inputs_far_outside_the_fit_are_flagged_naming_the_channel_and_the_model(records):
    assert main(["fit", "arx", "est.csv", "--out", "model", "--max-order", "3"]) == 0
    val = read_records("val.csv")[0]
    loud = Record(y=val.y, u=20 * val.u)
    with pytest.warns(MopWarning, match=r"fitted-arx was fitted on \(est.csv\): u0 is"):
        mop.load("model").simulate(loud, init=20)
    learned = mop.load("pretrained:lti-siso")
    learned.predictor_.input_stats = ([0.0, 0.0], [1.0, 1.0])  # the training inputs' (y0, u0) moments
    with pytest.warns(MopWarning, match=r"pretrained:lti-siso was trained on: u0 is"):
        learned.simulate(Record(y=val.y, u=1e3 * val.u), init=20)
    with warnings.catch_warnings():
        warnings.simplefilter("error", MopWarning)
        mop.load("model").simulate(val, init=20)  # inputs like the estimation record's: no warning


def test_learned_says_what_the_held_out_check_kept(records, capsys):
    from mop.estimators import Learned

    est = plant(1200, 5)
    model = Learned(progress=True, train__steps=3).fit(est)
    err = capsys.readouterr().err
    assert "Learned: held-out check" in err and model.selection_["kept"] in ("network", "arx", "n4sid")
    Learned(progress=False, train__steps=3).fit(est)
    assert "Learned:" not in capsys.readouterr().err
