"""Shipped pretrained models (mop.pretrained): loaded by name everywhere a run directory is accepted, their
cards are what the build measured, their weights are checked, and the build is one command."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

import mop
import mop.pretrained as pretrained
from mop.cli import main
from mop.errors import MopError
from mop.metrics import errors, mse_ratio_ci
from mop.predictors import make_predictor
from mop.pretrained.card import render_card
from mop.pretrained.catalog import CATALOG
from mop.runs import load_config
from mop.systems import generator, make_family
from mop.systems.base import Trajectories
from tests.reference import authors_linear_systems, filterpy_on, filterpy_predict, write_long_csv

SHIPPED = pretrained.shipped_names()
LATE = (20, 51)  # t in [20, 50]


@pytest.fixture(autouse=True)
def _one_thread(one_thread):
    yield


def family_traj(name: str, num_systems: int, seed: int, horizon: int = 50) -> Trajectories:
    system = load_config(f"pretrained:{name}").system
    family = make_family(system, dtype=torch.float64)
    return family.generate(num_systems, horizon, generator=generator(seed))


def late_mse(e: np.ndarray, stop: int = LATE[1]) -> float:
    """MSE over t in [20, stop) (the cards' late window: stop = horizon + 1)."""
    return float((e[:, LATE[0] : stop] ** 2).mean())


def test_every_catalog_model_is_shipped_within_10_mb():
    assert SHIPPED == sorted(e.name for e in CATALOG)
    total = sum((pretrained.ROOT / n / "model.safetensors").stat().st_size for n in SHIPPED)
    assert total <= 10e6


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_model_loads_everywhere_and_predicts_the_right_shape(name):
    traj = family_traj(name, 4, seed=1)
    a = mop.load(f"pretrained:{name}").predict(traj)
    b = make_predictor("mop", run_dir=f"pretrained:{name}").predict(traj)
    assert a.shape == traj.y.shape
    assert torch.isfinite(a).all()
    torch.testing.assert_close(a, b, rtol=0, atol=0)


@pytest.mark.parametrize("name", SHIPPED)
def test_ratio_on_the_cards_test_systems_is_the_cards_number(name):
    """The card's MOP/reference MSE over t in [20, T] on its own N = 500 test systems, regenerated from the
    card's test seed (seeded, so the same systems), to 1e-6 relative: the shipped weights and the inference
    path give the number the build measured (it agrees to ~1e-8; scaling MOP's predictions by 1.05 moves it
    by 1% or more)."""
    ev = pretrained.read_card(name)["evaluation"]
    r = ev["ratio_to_reference"][f"[20,{ev['horizon'] + 1})"]
    traj = family_traj(name, ev["num_systems"], ev["test_seed"], ev["horizon"])
    e_mop = errors(mop.load(f"pretrained:{name}").predict(traj), traj.y)
    e_ref = errors(make_predictor(ev["reference"]).predict(traj), traj.y)
    stop = ev["horizon"] + 1
    assert late_mse(e_mop, stop) / late_mse(e_ref, stop) == pytest.approx(r["ratio"], rel=1e-6)


@pytest.mark.parametrize("name", SHIPPED)
def test_card_is_rendered_from_card_json_and_records_the_files(name):
    path = pretrained.ROOT / name
    card = json.loads((path / "card.json").read_text())
    assert (path / "CARD.md").read_text() == render_card(card)
    assert card["sha256"] == pretrained.file_digests(path)
    assert card["size_bytes"] == (path / "model.safetensors").stat().st_size
    assert card["evaluation"]["num_systems"] == 500
    assert card["rebuild"].startswith(f"mop pretrained build {name} ")


@pytest.mark.parametrize("name", SHIPPED)
def test_card_names_the_input_features_the_shipped_config_turns_on(name):
    """A model reading the RLS / ARX prediction or the running scale says so on its card; a plain one not."""
    model = load_config(pretrained.ROOT / name).model
    lines = (pretrained.ROOT / name / "CARD.md").read_text().splitlines()
    line = next(x for x in lines if x.startswith("- model:"))
    fit = f"ARX({model.rls_order}, {model.arx_order})" if model.arx_order else f"RLS-AR({model.rls_order})"
    assert (f"the {fit} one-step prediction" in line) == (model.rls_order > 0), line
    assert ("the running output scale" in line) == (model.input_scale == "running"), line
    assert ("reads" in line) == (model.rls_order > 0 or model.input_scale == "running"), line


def test_linear_on_the_authors_generator_has_its_cards_ratio():
    """Trajectories of the authors' generator (numpy, tests/reference.py) and filterpy's KF: MOP/KF MSE over
    t in [20, 50] on 300 systems equals the card's (mop's generator, 500 systems) within a 99% two-sided
    test: |difference| <= 2.576 sd, the sd of each from its 95% CI (half-width / 1.96), in quadrature.
    Measured 1.0278 [1.0235, 1.0323] against the card's 1.0286 [1.0252, 1.0321]: tolerance 0.0074."""
    A, C, y = authors_linear_systems(300, seed=7)
    B, n, m = A.shape[0], A.shape[1], C.shape[1]
    eye = lambda d: np.broadcast_to(np.eye(d) * 0.01, (B, d, d))  # noqa: E731
    kf = filterpy_predict(A, C, eye(n), eye(m), y, np.zeros((B, n)), np.broadcast_to(np.eye(n), (B, n, n)))
    yhat = mop.load("pretrained:linear").predict(Trajectories(y=torch.tensor(y))).numpy()
    e_mop, e_kf = np.linalg.norm(yhat - y, axis=-1), np.linalg.norm(kf - y, axis=-1)
    ratio, low, high = mse_ratio_ci(e_mop, e_kf, *LATE, seed=0)
    card = pretrained.read_card("linear")["evaluation"]["ratio_to_reference"]["[20,51)"]
    sd = lambda lo, hi: (hi - lo) / 2 / 1.96  # noqa: E731
    tolerance = 2.576 * np.hypot(sd(low, high), sd(card["low"], card["high"]))
    assert abs(ratio - card["ratio"]) <= tolerance, (ratio, card, tolerance)


# --- integrity -----------------------------------------------------------------------------------------


@pytest.fixture
def copied_root(tmp_path, monkeypatch):
    """The shipped linear model copied to a private root that `pretrained:` resolves to."""
    shutil.copytree(pretrained.ROOT / "linear", tmp_path / "linear")
    monkeypatch.setattr(pretrained, "ROOT", tmp_path)
    return tmp_path / "linear"


def edit_config(path: Path) -> None:
    config = json.loads(path.read_text())
    config["train"]["seed"] += 1  # a valid config, another provenance
    path.write_text(json.dumps(config))


def flip_byte(path: Path, offset_from_end: int = 100) -> None:
    data = bytearray(path.read_bytes())
    data[-offset_from_end] ^= 0x01
    path.write_bytes(bytes(data))


@pytest.mark.parametrize(
    "damage",
    [
        lambda d: flip_byte(d / "model.safetensors"),  # one weight changed, the file still parses
        lambda d: (d / "model.safetensors").write_bytes((d / "model.safetensors").read_bytes()[:-1000]),
        lambda d: edit_config(d / "config.json"),
        lambda d: (d / "model.safetensors").unlink(),
    ],
    ids=["flipped-byte", "truncated", "config-edited", "missing"],
)
def test_tampered_or_truncated_weights_are_refused(copied_root, damage, tmp_path, capsys):
    traj = family_traj("linear", 2, seed=0)
    mop.load("pretrained:linear").predict(traj)  # the copy itself loads
    damage(copied_root)
    with pytest.raises(MopError, match="pretrained:linear"):
        mop.load("pretrained:linear")
    write_long_csv(tmp_path / "d.csv", [traj.y[0].numpy()])
    capsys.readouterr()
    assert main(["predict", "pretrained:linear", str(tmp_path / "d.csv")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "reinstall mop" in err


def test_a_flipped_weight_is_refused_by_the_weights_own_digest_too(copied_root):
    """safetensors itself reads a file with one flipped weight byte; the shipped weights carry the SHA-256 of
    their tensors in their metadata (as every run's do), so the load refuses it even without the card."""
    from safetensors.torch import load_file

    from mop.checkpoint import load_tensors

    flip_byte(copied_root / "model.safetensors")
    load_file(copied_root / "model.safetensors")  # the format alone does not notice
    with pytest.raises(MopError, match="sha256 differs"):
        load_tensors(copied_root / "model.safetensors")


def test_unknown_name_lists_the_shipped_ones(capsys, tmp_path):
    with pytest.raises(MopError, match="pretrained:linear"):
        mop.load("pretrained:nope")
    (tmp_path / "d.csv").write_text("trajectory,t,y0\na,0,1\na,1,2\n")
    assert main(["predict", "pretrained:nope", str(tmp_path / "d.csv")]) == 2
    assert "no pretrained model 'nope'" in capsys.readouterr().err


# --- mop predict ---------------------------------------------------------------------------------------


def test_predict_by_name_window_stream_and_steps(tmp_path):
    traj = family_traj("linear", 5, seed=3)
    y = traj.y.float().numpy()
    np.savez(tmp_path / "d.npz", y=y)
    expected = mop.load("pretrained:linear").predict(Trajectories(y=torch.tensor(y))).numpy()
    for flags in ([], ["--stream"]):
        out = tmp_path / f"p{len(flags)}.npz"
        assert main(["predict", "pretrained:linear", str(tmp_path / "d.npz"), "--out", str(out), *flags]) == 0
        np.testing.assert_allclose(np.load(out)["yhat"], expected, rtol=1e-5, atol=1e-6)  # T = C: equal
    out = tmp_path / "k.npz"
    assert (
        main(["predict", "pretrained:linear", str(tmp_path / "d.npz"), "--steps", "3", "--out", str(out)])
        == 0
    )
    ahead = np.load(out)["yhat"]
    assert ahead.shape == (5, 51, 3, 5)
    np.testing.assert_allclose(ahead[:, :, 0], expected, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize(
    "name, outputs, inputs, word",
    [
        ("linear", 2, 0, "output_dim=2"),
        ("quadrotor", 3, 0, "0 inputs u"),
        ("linear", 5, 2, "2 inputs u"),
        ("linear-inputs", 5, 0, "0 inputs u"),
        # a model with the observation mask (its mask channels are its own outputs', not the data's)
        ("lti-siso", 3, 1, "trained with output_dim=1 and 1 inputs u"),
    ],
)
def test_predict_refuses_other_dimensions_in_one_line(name, outputs, inputs, word, tmp_path, capsys):
    rng = np.random.default_rng(0)
    data = {"y": rng.normal(size=(2, 11, outputs))}
    if inputs:
        data["u"] = rng.normal(size=(2, 11, inputs))
    np.savez(tmp_path / "d.npz", **data)
    capsys.readouterr()
    assert main(["predict", f"pretrained:{name}", str(tmp_path / "d.npz")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and word in err and f"pretrained:{name}" in err
    assert not list(tmp_path.glob("d_*pred.npz"))
    fits = [n for n in SHIPPED if _dims_of(n) == (outputs, inputs)]  # from each shipped config, by hand
    named = ", ".join(f"pretrained:{n}" for n in fits)
    hint = f"shipped models for m={outputs}, k={inputs}: {named}"
    hint = hint if fits else "mop train --data FILE --out DIR"
    assert err.rstrip().endswith(hint)


def _dims_of(name: str) -> tuple[int, int]:
    model = json.loads((pretrained.ROOT / name / "config.json").read_text())["model"]
    mask = model["output_dim"] if model.get("observation_mask") else 0
    return model["output_dim"], model["input_dim"] - model["output_dim"] - mask


def test_fitting_names_the_models_of_given_dimensions(tmp_path):
    for name, model in {
        "a": {"output_dim": 1, "input_dim": 2},
        "b": {"output_dim": 1, "input_dim": 3, "observation_mask": True},
        "c": {"output_dim": 2, "input_dim": 2},
    }.items():
        (tmp_path / name).mkdir()
        (tmp_path / name / "config.json").write_text(json.dumps({"model": model}))
        (tmp_path / name / "card.json").write_text("{}")
    assert pretrained.fitting(1, 1, tmp_path) == ["pretrained:a", "pretrained:b"]
    assert pretrained.fitting(2, 0, tmp_path) == ["pretrained:c"]
    assert pretrained.fitting(3, 0, tmp_path) == []


# --- listing, reproduce, experiment files --------------------------------------------------------------


def test_mop_pretrained_lists_every_model_and_shows_its_card(capsys):
    assert main(["pretrained"]) == 0
    out = capsys.readouterr().out
    for name in SHIPPED:
        assert f"pretrained:{name}:" in out and str(pretrained.ROOT / name / "CARD.md") in out
        m, k = _dims_of(name)
        assert f"pretrained:{name}: m={m} outputs, k={k} inputs, class " in out
    assert f"{len(SHIPPED)} models" in out
    assert main(["pretrained", "show", "quadrotor"]) == 0
    assert capsys.readouterr().out == (pretrained.ROOT / "quadrotor" / "CARD.md").read_text()


def test_reproduce_pretrained_trains_nothing(tmp_path, tiny_smoke):
    out = tmp_path / "linear"
    argv = ["reproduce", "linear", "--pretrained", "--preset", "smoke", "--out", str(out), "--quiet"]
    assert main(argv) == 0
    data = json.loads((out / "eval.json").read_text())
    assert data["runs"] == {"mop [test]": "pretrained:linear"}
    assert data["settings"]["pretrained"] is True
    assert not (tmp_path / "runs").exists()


def test_reproduce_pretrained_without_a_shipped_model_fails_before_work(tmp_path, capsys):
    out = tmp_path / "ns"
    assert main(["reproduce", "noise-shift", "--pretrained", "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no pretrained model is shipped" in err
    assert not out.exists()


def test_experiment_file_runs_a_shipped_model(tmp_path, tiny_smoke):
    (tmp_path / "exp.toml").write_text(
        'name = "shipped"\ntitle = "t"\npredictors = ["mop", "kalman"]\n'
        '[train]\n"system.family" = "linear"\n[runs]\nmop = "pretrained:linear"\n'
    )
    argv = [
        "reproduce",
        str(tmp_path / "exp.toml"),
        "--preset",
        "smoke",
        "--out",
        str(tmp_path / "o"),
        "--quiet",
    ]
    assert main(argv) == 0
    data = json.loads((tmp_path / "o" / "eval.json").read_text())
    assert data["runs"] == {"mop [test]": "pretrained:linear"}
    assert not (tmp_path / "runs").exists()


# --- the build ------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_build_writes_measured_numbers_and_is_deterministic(tmp_path, tiny_smoke, monkeypatch):
    """A smoke build of `linear`: its card's MOP/KF ratio is recomputed independently (the shipped files,
    filterpy's KF, a numpy MSE on the card's test systems); a second build from scratch gives the same
    weights bit for bit."""
    import mop.experiments.pretrained_build as build
    from mop.experiments.evaluating import test_trajectories

    monkeypatch.setattr(build, "NOISE_SHIFT_SYSTEMS", 4)
    common = ["pretrained", "build", "linear", "--preset", "smoke", "--threads", "1", "--quiet"]
    for i in (1, 2):
        argv = [*common, "--work", str(tmp_path / f"w{i}"), "--out", str(tmp_path / f"o{i}")]
        assert main(argv) == 0
    shipped = tmp_path / "o1" / "linear"
    card = json.loads((shipped / "card.json").read_text())
    assert card["sha256"] == json.loads((tmp_path / "o2" / "linear" / "card.json").read_text())["sha256"]
    assert (shipped / "CARD.md").read_text() == render_card(card)
    assert card["rebuild"] == "mop pretrained build linear --threads 1 --preset smoke"
    ev = card["evaluation"]
    traj = test_trajectories(load_config(shipped).system, ev["num_systems"], ev["horizon"], seed=0)
    e_mop = np.linalg.norm(mop.load(shipped).predict(traj).numpy() - traj.y.numpy(), axis=-1)
    e_kf = np.linalg.norm(filterpy_on(traj) - traj.y.numpy(), axis=-1)
    assert ev["ratio_to_reference"]["[20,51)"]["ratio"] == pytest.approx(
        late_mse(e_mop) / late_mse(e_kf), rel=1e-6
    )
    assert card["forecast"]["error"]["mop"][0] == pytest.approx(e_mop[:, 20:].mean(), rel=1e-6)


def test_build_reads_overrides_after_the_options():
    from mop.cli import build_parser

    argv = ["pretrained", "build", "quadrotor", "--threads", "1", "train.steps=1500", "--quiet"]
    args = build_parser("pretrained").parse_args(argv)
    assert (args.names, args.overrides, args.threads) == (["quadrotor"], ["train.steps=1500"], 1)


def test_the_build_measures_a_condition_as_the_report_does(tmp_path, tiny_smoke, monkeypatch):
    """One evaluation: the card's numbers (mop.experiments.pretrained_build.measure) are the report's, bit for
    bit, on a condition with missing outputs, and both name the experiment's best predictor: its reference
    when it names none, even where another predictor (here the KF, against `last`) has the lower error."""
    import dataclasses

    import mop.experiments.pretrained_build as build
    from mop.experiments import Condition, get_experiment
    from mop.experiments.runner import run_experiment
    from mop.pretrained.catalog import ShippedModel

    monkeypatch.setattr(build, "NOISE_SHIFT_SYSTEMS", 2)
    exp = dataclasses.replace(
        get_experiment("missing-data"),
        name="one-evaluation",
        reference="last",
        conditions=(Condition("p", missing={"rate": 0.3}),),
        claims=(),
        figures=(),
    )
    monkeypatch.setattr(build, "get_experiment", lambda name: exp)
    run_experiment(exp, "smoke", tmp_path / "out", runs_dir=tmp_path / "runs", progress=False)
    report = json.loads((tmp_path / "out" / "eval.json").read_text())["conditions"]["p"]
    (run_dir,) = (tmp_path / "runs").iterdir()
    entry = ShippedModel("x", exp.name, "s", "n", preset="smoke")
    ev = build.measure(entry, run_dir, progress=False)["evaluation"]
    assert ev["errors"] == {n: p["window_error"] for n, p in report["predictors"].items()}
    assert (
        report["predictors"]["kalman"]["window_squared_error"]["all"]
        < (report["predictors"]["last"]["window_squared_error"]["all"])
    )
    assert ev["best"] == report["to_best"]["predictor"] == "last"
    late = ev["ratio_to_best"][f"[20,{ev['horizon'] + 1})"]
    assert late == {k: report["to_best"][k] for k in ("ratio", "low", "high")}


# --- class models ---------------------------------------------------------------------------------------

CLASS_MODELS = [n for n in SHIPPED if load_config(f"pretrained:{n}").model.record_norm == "causal"]


@pytest.mark.parametrize("name", CLASS_MODELS)
def test_class_model_predicts_and_simulates_any_units_zero_shot(name, tmp_path, capsys):
    """mop predict on 3 records of the class, as is and in other units (y -> 1000 y + 5, u -> 0.1 u - 2):
    one-step predictions and the free-run simulation after 300 steps come back as 1000 x + 5 (the model
    runs in float32, and the least-squares feature (P_0 = 1e4 I) amplifies its rounding where the
    regressors are nearly collinear, as a tank at its rim: 5e-4 relative; measured up to 2.6e-4)."""
    traj = family_traj(name, 3, seed=11, horizon=400)
    y, u = traj.y.numpy(), traj.u.numpy()
    np.savez(tmp_path / "a.npz", y=y, u=u)
    np.savez(tmp_path / "b.npz", y=1000 * y + 5, u=0.1 * u - 2)
    out = {}
    for f in ("a", "b"):
        for flag, key in ((["--simulate", "300"], "ysim"), ([], "yhat")):
            target = tmp_path / f"{f}_{key}.npz"
            assert (
                main(
                    ["predict", f"pretrained:{name}", str(tmp_path / f"{f}.npz"), "--out", str(target), *flag]
                )
                == 0
            )
            out[f, key] = np.load(target)[key]
    for key, start in (("yhat", 1), ("ysim", 0)):  # yhat_0 is the data-free prediction
        got, want = out["b", key][:, start:], 1000 * out["a", key][:, start:] + 5
        np.testing.assert_allclose(got, want, rtol=5e-4, atol=1e-2)
    assert np.sqrt(((out["a", "ysim"] - y[:, 300:]) ** 2).mean()) < 0.5 * y[:, 300:].std()


@pytest.mark.slow
def test_zero_shot_experiment_file_evaluates_the_shipped_class_model_untrained(tmp_path):
    """examples/class_zero_shot.toml at the smoke preset: every condition (its class, noisy, the neighbouring
    Wiener-Hammerstein class) runs pretrained:lti-siso, nothing is trained, and the lti-siso condition's
    simulation RMSE is the shipped model's own simulation of those test systems (recomputed here)."""
    from mop.experiments.evaluating import test_trajectories

    out = tmp_path / "zs"
    toml = Path(__file__).resolve().parents[1] / "examples" / "class_zero_shot.toml"
    assert main(["reproduce", str(toml), "--preset", "smoke", "--out", str(out), "--quiet"]) == 0
    data = json.loads((out / "eval.json").read_text())
    assert set(data["runs"].values()) == {"pretrained:lti-siso"} and len(data["runs"]) == 3
    assert not (tmp_path / "runs").exists()
    cond = data["conditions"]["lti-siso"]
    traj = test_trajectories(load_config("pretrained:lti-siso").system, cond["num_systems"], 499, seed=0)
    sim = mop.load("pretrained:lti-siso").simulate(traj, 400).double()
    rmse = float(((sim - traj.y[:, 400:].double()) ** 2).mean((1, 2)).sqrt().mean())
    assert cond["simulation"]["rmse"]["mop"]["simulation_rmse"] == pytest.approx(rmse, rel=1e-6)
