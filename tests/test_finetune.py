"""Fine-tuning (`mop train --data FILE --init RUN`, mop.recipe.source): step 0 is the source's weights and
normalisation, a mismatched architecture is refused in one line, and on records of held-out systems a
fine-tuned class model beats the zero-shot one and one trained from scratch for as many steps."""

import json

import numpy as np
import pytest
import torch

import mop
from mop.cli import main
from mop.config import ModelConfig, RunConfig, SystemConfig, TrainConfig, from_dict
from mop.errors import MopError
from mop.experiments.presets import default_preset, preset_config
from mop.recipe.finetune import FINE_TUNE_LR_FACTOR, FINE_TUNE_STEPS
from mop.recipe.layers import training_config
from mop.runs import load_predictor
from mop.systems import generator, make_family
from mop.systems.base import Trajectories
from mop.train import train

# the transformer (the records recipe's deep LRU reads no feature whose orders a fine-tune could change)
TINY = ["model.num_layers=1", "model.width=16", "model.num_heads=2", "model.context=20", "train.horizon=20"]
GPT = ["model.arch=gpt"]
SMALL = [*TINY, "train.batch_size=4", "train.log_every=1", "train.checkpoint_every=1000"]


@pytest.fixture(autouse=True)
def _one_thread(one_thread):
    yield


def record(path, seed: int, scale: float = 1.0, T: int = 300) -> str:
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(1, T + 1, 1))
    y = np.zeros((1, T + 1, 1))
    for t in range(T):
        y[0, t + 1] = 0.8 * y[0, t] + 0.5 * u[0, t] + 0.05 * rng.normal()
    np.savez(path, y=scale * y + 3.0, u=u)
    return str(path)


def weights(run) -> dict[str, torch.Tensor]:
    """The run's network's weights (also where its held-out check kept a fitted linear model)."""
    return {k: v.clone() for k, v in load_predictor(str(run)).model.state_dict().items()}


def test_fine_tuning_starts_from_the_source_weights_and_keeps_its_normalisation(tmp_path):
    """A fine-tune of 1 step at lr 1e-30 is the source model (weights and predictions on another record),
    its normalisation is the source's (not refitted on the new record, whose scale is 10x), and config.json
    names the source."""
    first, other = record(tmp_path / "a.npz", 0), record(tmp_path / "b.npz", 1, scale=10.0)
    src, ft = tmp_path / "src", tmp_path / "ft"
    own = ["train.steps=3", "data.feature_input=none", *SMALL]  # the network alone (no feature refitted)
    assert main(["train", "--data", first, "--out", str(src), "--no-progress", *own]) == 0
    argv = ["train", "--data", other, "--init", str(src), "--out", str(ft), "--no-progress"]
    assert main([*argv, "train.steps=1", "train.lr=1e-30"]) == 0
    a, b = weights(src), weights(ft)
    assert a.keys() == b.keys()
    for k in a:
        torch.testing.assert_close(b[k], a[k], rtol=0, atol=1e-12)
    saved, source = (json.loads((d / "config.json").read_text()) for d in (ft, src))
    assert saved["train"]["init"] == str(src)
    assert all(saved["data"][k] == source["data"][k] for k in ("y_mean", "y_std", "u_mean", "u_std"))
    traj = Trajectories(*(torch.from_numpy(np.load(other)[k]) for k in ("y", "u")))
    torch.testing.assert_close(
        load_predictor(str(ft)).predict(traj), load_predictor(str(src)).predict(traj), atol=1e-9, rtol=0
    )


def test_the_default_schedule_and_refusals(tmp_path, capsys):
    first = record(tmp_path / "a.npz", 0)
    src = tmp_path / "src"
    argv = ["train", "--data", first, "--out", str(src), "--no-progress", "train.steps=1", *SMALL, *GPT]
    assert main(argv) == 0
    config = training_config(None, data=first, init=str(src))
    base = from_dict(RunConfig, json.loads((src / "config.json").read_text()))
    assert config.train.steps == FINE_TUNE_STEPS and config.train.warmup_steps == 0
    assert config.train.lr == pytest.approx(base.train.lr * FINE_TUNE_LR_FACTOR)
    assert config.model == base.model and config.train.horizon == base.train.horizon == 20
    short = training_config(None, data=record(tmp_path / "s.npz", 2, T=150), init=str(src))
    assert short.train.horizon == 15  # the last ceil(0.1 x 151) = 16 steps validate: windows of 16 fit
    # the windows follow the split the overrides ask for: half the record validates, so 20 fit again
    halves = ["data.validation_fraction=0.5"]
    wide = training_config(None, data=str(tmp_path / "s.npz"), init=str(src), overrides=halves)
    assert wide.train.horizon == 20
    capsys.readouterr()
    out = tmp_path / "bad"
    argv = [
        "train",
        "--data",
        first,
        "--init",
        str(src),
        "--out",
        str(out),
        "--no-progress",
        "model.width=32",
    ]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "model.width=16" in err and "32" in err and "--init" in err
    assert not (out / "model.safetensors").exists()
    # how the loss weighs positions is the fine-tune's own choice, not the architecture (source.LOSS_KEYS)
    loss = [*argv[:-1], "model.horizon_loss=balanced", "train.steps=1"]
    assert main(loss) == 0
    assert json.loads((out / "config.json").read_text())["model"]["horizon_loss"] == "balanced"
    # the feature's orders are no architecture (the network reads its one-step prediction) while the
    # feature stays ARX: other orders fine-tune; turning the input lags off is refused
    p, q = base.model.rls_order, base.model.arx_order
    assert p > 0 and q > 0
    out = tmp_path / "orders"
    tuned = ["train", "--data", first, "--init", str(src), "--no-progress", "train.steps=1"]
    assert main([*tuned, "--out", str(out), f"model.rls_order={p + 1}", f"model.arx_order={q + 1}"]) == 0
    saved = json.loads((out / "config.json").read_text())["model"]
    assert (saved["rls_order"], saved["arx_order"]) == (p + 1, q + 1)
    # the source's start was fitted at its orders: the fine-tune refits it at the new ones (one output)
    cubes = saved.get("rls_cubes", 0)  # the source's cubed lags, kept (the records recipe may choose some)
    assert (
        len(saved["rls_prior"])
        == p + 1 + cubes + q + 1 + int(saved["rls_offset"])
        != len(base.model.rls_prior)
    )
    capsys.readouterr()
    assert main([*tuned, "--out", str(tmp_path / "ar"), "model.arx_order=0"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "model.arx_order" in err
    out = tmp_path / "bad2"
    assert main(["train", "--init", str(src), "--preset", "smoke", "--out", str(out)]) == 2
    assert "--preset smoke" in capsys.readouterr().err


CLASS = SystemConfig.resolve_class({"family": "lti-siso"})(max_order=2, noise_std=0.2)
FEATURE = dict(rls_order=2, arx_order=2, rls_offset=True)


def held_out_records(tmp_path, num: int, T: int = 600) -> list[tuple[str, Trajectories]]:
    """(training record .npz, a second record of the same system) for `num` systems the class model never
    saw (a generator seeded apart)."""
    family = make_family(CLASS, dtype=torch.float64)
    params = family.sample(num, generator=generator(99))
    out = []
    for i in range(num):
        p = params.select(slice(i, i + 1))
        fit, test = (family.simulate(p, T, generator=generator(100 + 2 * i + j)) for j in (0, 1))
        path = tmp_path / f"sys{i}.npz"
        np.savez(path, y=fit.y.numpy(), u=fit.u.numpy())
        out.append((str(path), test))
    return out


def rmse(run, traj: Trajectories) -> float:
    yhat = mop.load(str(run)).predict(traj)
    return float(((yhat - traj.y)[:, 20:] ** 2).mean().sqrt())


@pytest.mark.slow
def test_fine_tuned_beats_zero_shot_and_from_scratch_on_held_out_systems(tmp_path):
    """A tiny class model (250 steps on lti-siso of order <= 2, record_norm causal) on 4 held-out systems:
    fine-tuned for 60 steps (the default schedule's lr, a tenth of the class model's) it is below the
    zero-shot model, and below a model of the same architecture trained from scratch for 60 steps at that
    lr, on a second record of each system (one-step RMSE over t >= 20), on the mean over systems and on at
    least 3 of the 4 (a statistical margin: the fine-tune keeps the class model's start)."""
    cfg = RunConfig(
        system=CLASS,
        model=ModelConfig(num_layers=1, num_heads=2, width=32, context=40, record_norm="causal", **FEATURE),
        train=TrainConfig(steps=250, batch_size=16, horizon=40, lr=3e-3, num_source_systems=0, log_every=50),
    )
    cls = train(cfg, tmp_path / "class", progress=False)
    common = ["--no-progress", "train.steps=60", "train.batch_size=16", "train.log_every=50"]
    scores = []
    for i, (path, test) in enumerate(held_out_records(tmp_path, 4)):
        ft, scratch = tmp_path / f"ft{i}", tmp_path / f"scratch{i}"
        assert main(["train", "--data", path, "--init", str(cls), "--out", str(ft), *common]) == 0
        from_scratch = [*common, "train.lr=3e-4", "model.num_layers=1", "model.num_heads=2", "model.width=32"]
        argv = ["train", "--data", path, "--out", str(scratch), *from_scratch, "model.context=40"]
        feature = [f"model.{k}={str(v).lower()}" for k, v in FEATURE.items()]
        assert (
            main([*argv, "train.horizon=40", "model.record_norm=causal", "model.features=given", *feature])
            == 0
        )
        scores.append((rmse(cls, test), rmse(ft, test), rmse(scratch, test)))
    zero, tuned, fresh = np.array(scores).T
    assert tuned.mean() < zero.mean() and tuned.mean() < fresh.mean(), scores
    assert (tuned < zero).sum() >= 3 and (tuned < fresh).sum() >= 3, scores


def test_a_class_model_fine_tuned_on_a_record_starts_its_moments_at_the_records(tmp_path):
    """`mop train --data REC --init pretrained:cascaded-tanks` (a class model: record_norm, trained on no
    recorded data, so the run normalises by REC's own moments) starts record_norm's moments from
    RECORD_PRIOR_STEPS pseudo-steps at them, beside the feature's least-squares start; an override wins, and
    the key is no architecture key (the source has 0)."""
    from mop.recipe.finetune import RECORD_PRIOR_STEPS

    path = record(tmp_path / "r.npz", 0)
    config = training_config(None, data=path, init="pretrained:cascaded-tanks")
    assert config.model.record_prior_steps == RECORD_PRIOR_STEPS > 0 and config.model.rls_prior == "fit"
    off = training_config(
        None, data=path, init="pretrained:cascaded-tanks", overrides=["model.record_prior_steps=0"]
    )
    assert off.model.record_prior_steps == 0 and off.model.rls_prior == "fit"
    assert (off.model.rls_order, off.model.arx_order) == (config.model.rls_order, config.model.arx_order)
    # a source trained on recorded data keeps its normalisation, so 0 and 1 are not this record's moments
    src = tmp_path / "src"
    own = ["model.record_norm=causal", "model.features=given", "model.rls_order=2", "model.arx_order=2"]
    argv = ["train", "--data", path, "--out", str(src), "--no-progress", "train.steps=1", *SMALL, *own]
    assert main(argv) == 0
    kept = training_config(None, data=path, init=str(src)).model
    assert kept.rls_prior == "fit" and kept.record_prior_steps == 0


def test_a_class_model_fine_tuned_on_a_record_reads_the_arx_orders_mop_fit_arx_picks(tmp_path, capsys):
    """The fine-tune's feature has the orders `mop fit arx REC` chooses on the whole record, not the
    source's ARX(10, 10), so simulated with its correction's gain 0 it is the user's fitted linear model;
    an override of the orders wins."""
    est = record(tmp_path / "est.npz", 0)
    assert main(["fit", "arx", est, "--out", str(tmp_path / "arx")]) == 0
    orders = json.loads((tmp_path / "arx" / "fitted.json").read_text())["orders"]
    config = training_config(None, data=est, init="pretrained:cascaded-tanks")
    assert (config.model.rls_order, config.model.arx_order) == (orders["p"], orders["q"]) != (10, 10)
    kept = ["model.rls_order=10", "model.arx_order=10"]
    source = training_config(None, data=est, init="pretrained:cascaded-tanks", overrides=kept)
    assert (source.model.rls_order, source.model.arx_order) == (10, 10)


def test_a_short_record_fine_tunes_with_the_orders_it_allows(tmp_path, capsys):
    """A record too short for `mop fit arx`'s orders up to 10 (which then names the largest --max-order it
    allows) fine-tunes with the orders of `mop fit arx --max-order P`, and trains the records recipe with
    orders up to P; one too short for any keeps the source's ARX(10, 10)."""
    est = record(tmp_path / "short.npz", 0, T=30)
    capsys.readouterr()
    assert main(["fit", "arx", est, "--out", str(tmp_path / "refused")]) == 2
    largest = int(capsys.readouterr().err.split("--max-order ")[1].split()[0])
    assert 1 <= largest < 10
    assert main(["fit", "arx", est, "--max-order", str(largest), "--out", str(tmp_path / "arx")]) == 0
    orders = json.loads((tmp_path / "arx" / "fitted.json").read_text())["orders"]
    config = training_config(None, data=est, init="pretrained:cascaded-tanks")
    assert (config.model.rls_order, config.model.arx_order) == (orders["p"], orders["q"])
    # the records recipe from scratch chooses its orders the same way on the record's training part (90%)
    recipe = training_config(None, data=est, overrides=GPT).model
    assert 1 <= recipe.rls_order <= largest and 1 <= recipe.arx_order <= largest
    tiny = training_config(None, data=record(tmp_path / "tiny.npz", 0, T=3), init="pretrained:cascaded-tanks")
    assert (tiny.model.rls_order, tiny.model.arx_order) == (10, 10)
    # from scratch the records recipe needs its feature: a record too short for any order is refused
    with pytest.raises(MopError, match="too short to fit the records recipe's ARX feature"):
        training_config(None, data=str(tmp_path / "tiny.npz"))


def test_a_cubic_class_model_fine_tunes_with_its_own_lags(tmp_path):
    """pretrained:duffing reads the cubic NARX with 10 output lags, all cubed: its fine-tune keeps the
    source's lags (the ARX orders `mop fit arx` picks may be fewer than the cubed lags, which
    model.rls_cubes refuses) and starts the feature from its least-squares fit."""
    est = record(tmp_path / "est.npz", 0)
    config = training_config(None, data=est, init="pretrained:duffing")
    m = config.model
    assert (m.rls_order, m.arx_order, m.rls_cubes) == (10, 10, 10) and m.rls_prior == "fit"
    linear = training_config(None, data=est, init="pretrained:cascaded-tanks").model
    assert (linear.rls_order, linear.arx_order) != (10, 10)  # the linear class takes mop fit arx's orders


def test_a_fine_tune_may_drop_the_residual_scale_and_simulate_by_rollout(tmp_path, capsys):
    """A fine-tune of a model with a residual scale (model.residual_scale, record_norm) may drop it and
    simulate by feeding its predictions back (model.forecast_mode=rollout): step 0 holds every source
    weight, the read-in without the columns of log(c_t / std_t(y)), the last output_dim (at lr 1e-30 the
    weights stay those); adding a residual scale to a source without one is still refused."""
    first = record(tmp_path / "a.npz", 0)
    src = tmp_path / "src"
    own = [
        "model.record_norm=causal",
        "model.features=given",
        "model.rls_order=2",
        "model.arx_order=2",
        "model.observation_mask=true",
        "model.forecast_mode=gap",
    ]
    argv = ["train", "--data", first, "--out", str(src), "--no-progress", "train.steps=1", *SMALL, *own]
    assert main([*argv, "model.residual_scale=running"]) == 0
    tuned = ["train", "--data", first, "--init", str(src), "--no-progress", "train.steps=1", "train.lr=1e-30"]
    drop = ["model.residual_scale=none", "model.forecast_mode=rollout"]
    assert main([*tuned, "--out", str(tmp_path / "ft"), *drop]) == 0
    saved = json.loads((tmp_path / "ft" / "config.json").read_text())["model"]
    before = json.loads((src / "config.json").read_text())["model"]
    assert (before["residual_scale"], before["forecast_mode"]) == ("running", "gap")
    # config.json leaves defaults out: none and rollout
    assert (
        saved.get("residual_scale", "none") == "none" and saved.get("forecast_mode", "rollout") == "rollout"
    )
    a, b = weights(src), weights(tmp_path / "ft")
    assert a.keys() == b.keys()
    m = 1
    assert b["read_in.weight"].shape[1] == a["read_in.weight"].shape[1] - m
    torch.testing.assert_close(b["read_in.weight"], a["read_in.weight"][:, :-m], rtol=0, atol=1e-12)
    # the held-out check after training may keep the correction at a gain g < 1: the read-out times g
    kept = json.loads((tmp_path / "ft" / "selection.json").read_text())
    gain = kept["gain"] if kept["kept"] == "network" else 1.0
    for k in sorted(a.keys() - {"read_in.weight"}):
        expected = gain * a[k] if k.startswith("read_out.") else a[k]
        torch.testing.assert_close(b[k], expected, rtol=0, atol=1e-12, msg=k)
    plain = tmp_path / "plain"
    assert main([*argv[:4], str(plain), *argv[5:]]) == 0
    capsys.readouterr()
    adding = [*tuned[:4], str(plain), *tuned[5:], "--out", str(tmp_path / "add")]
    assert main([*adding, "model.residual_scale=running"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "model.residual_scale" in err


def test_a_model_trained_with_estimation_prefixes_fine_tunes_as_the_records_recipe(tmp_path, capsys):
    """A network of the records recipe's shape (no record_norm) pretrained on a class with each window read
    after its estimation record's fit (train.context_prefix) is a records start: its fine-tune is the
    records recipe from its weights, the feature and the steps the recipe picks on the record from scratch
    (orders, cubes, least-squares start; the budget's plan) at the default preset's rate. The same network
    pretrained without the prefix identified its feature in each window: it keeps that and the short
    fine-tune, and --budget is refused for it."""
    est = record(tmp_path / "est.npz", 0)
    shape = [
        *TINY,
        "train.batch_size=2",
        "train.steps=1",
        "train.simulate_after=0",
        "train.num_source_systems=0",
        "model.record_norm=none",
        "model.residual_scale=none",
        "model.observation_mask=false",
        "model.forecast_mode=rollout",
        "model.rls_order=3",
        "model.arx_order=3",
    ]
    runs = {}
    for prefix in (0, 100):
        runs[prefix] = tmp_path / f"src{prefix}"
        argv = ["train", "class-lti-siso", "--preset", "smoke", "--out", str(runs[prefix]), "--no-progress"]
        assert main([*argv, *shape, f"train.context_prefix={prefix}"]) == 0
    scratch = training_config(None, data=est, overrides=GPT)  # the transformer recipe it starts
    keys = ("rls_order", "arx_order", "rls_cubes", "rls_offset", "rls_prior", "rls_fixed")
    base = preset_config(default_preset()).train
    for minutes in (None, 50.0):
        tuned = training_config(None, data=est, init=str(runs[100]), budget=minutes)
        recipe = (
            scratch if minutes is None else training_config(None, data=est, overrides=GPT, budget=minutes)
        )
        assert all(getattr(tuned.model, k) == getattr(recipe.model, k) for k in keys)
        assert tuned.model.rls_prior == "fit" and tuned.train.steps == recipe.train.steps
        assert (tuned.train.lr, tuned.train.lr_schedule) == (base.lr, base.lr_schedule)
        assert tuned.model.width == 16 and tuned.train.init == str(runs[100])  # the source's network
    # an override of the feature wins, started from the record's fit as a class model's
    named = training_config(None, data=est, init=str(runs[100]), overrides=["model.rls_order=2"]).model
    assert named.rls_order == 2 and named.rls_prior == "fit"
    plain = training_config(None, data=est, init=str(runs[0]))
    assert plain.model.rls_prior == "none" and (plain.model.rls_order, plain.model.arx_order) == (3, 3)
    assert plain.train.steps == FINE_TUNE_STEPS and plain.train.lr != base.lr
    with pytest.raises(MopError, match="a fine-tune .--init. has its own schedule"):
        training_config(None, data=est, init=str(runs[0]), budget=5.0)
