"""The held-out check's line says what the run keeps in plain words (issue #66, C): where the correction's
best gain is 0 the network did not help and the model is the feature it names, with the training that
took; where the network is kept at a gain the line names it and the held-out scores; where the ARX wins it
says so."""

import json

from mop.config import RunConfig, apply_overrides
from mop.recipe.selection import feature_alone, kept_model, selection_line, training_time

FEATURE = "the ARX(40, 40) with an intercept fixed at its least-squares fit on the training part"


def result(kept: str, gain: float | None) -> dict:
    scores = [0.0111, 0.0112, 0.0113, 0.0114, 0.0115]
    return {
        "format": 4,
        "held_out_steps": 600,
        "long_run_steps": 2000,
        "init": 50,
        "gains": [0.0, 0.25, 0.5, 0.75, 1.0],
        "network": {"gap": [{"score": v} for v in scores], "rollout": [{"score": 2 * v} for v in scores]},
        "network_rmse": 0.0115,
        "linear_models": {"arx": {"score": 0.0120}, "n4sid": {"score": 0.0130}},
        "linear_orders": {"arx": {"p": 7, "q": 5}, "n4sid": {"n": 4}},
        "kept": kept,
        "reading": "gap" if kept == "network" else None,
        "gain": gain,
    }


def test_gain_zero_says_the_network_did_not_help_and_names_the_feature_and_the_training():
    line = selection_line(result("network", 0.0), FEATURE, "1875 steps, about 2 min 31 s")
    assert "the network's correction did not help" in line
    assert f"the run's model is its feature alone, {FEATURE}" in line
    assert "gain 0, 0.0111" in line and "1875 steps, about 2 min 31 s of training" in line
    assert "keeps the network" not in line


def test_a_kept_network_names_its_gain_and_the_held_out_scores():
    line = selection_line(result("network", 0.5), FEATURE, "100 steps, about 5 s")
    assert "keeps the network with its correction at gain 0.5" in line
    assert all(f"{v:.4g}" in line for v in (0.0113, 0.0115, 0.0111, 0.0120))
    assert "did not help" not in line
    assert "keeps the network as trained" in selection_line(result("network", 1.0))


def test_a_kept_linear_model_says_which():
    line = selection_line(result("arx", None), FEATURE, "100 steps, about 5 s")
    assert "keeps the fitted ARX(7, 5)" in line and "did not improve on it" in line
    assert "keeps the network" not in line and "fitted N4SID(n=4) 0.013" in line
    assert "keeps the fitted N4SID(n=4) (fitted.json, as `mop fit n4sid` writes it)" in selection_line(
        result("n4sid", None)
    )


def test_the_reading_kept_is_named():
    line = selection_line(result("network", 0.5))
    assert "reading its simulated outputs as missing" in line
    fed_back = {**result("network", 1.0), "reading": "rollout"}
    assert "keeps the network as trained, feeding its predictions back as outputs" in selection_line(fed_back)


def test_the_feature_and_the_training_time_in_words(tmp_path):
    fixed = apply_overrides(
        RunConfig(),
        ["model.rls_order=40", "model.arx_order=40", "model.rls_offset=true", "model.rls_prior=fit"]
        + ["model.rls_fixed=true"],
    )
    assert feature_alone(fixed) == FEATURE
    lines = [{"step": 50, "loss": 1.0, "steps_per_s": 10.0}, {"step": 50, "val_loss": 1.0}]
    lines.append({"step": 100, "loss": 1.0, "steps_per_s": 50.0})
    (tmp_path / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in lines))
    assert training_time(tmp_path) == "100 steps, about 6 s"  # 50 / 10 + 50 / 50 seconds
    assert training_time(tmp_path / "none") is None


def test_what_a_run_keeps_is_named_with_its_orders():
    """`mop benchmark`'s warning names the least-squares model a run kept as the check's line does: a long
    ARX kept as the feature is the NARX of no cubes it is, not its file kind."""
    feature = {"kept": "cubic-narx", "linear_orders": {"cubic-narx": {"p": 40, "q": 40, "c": 0}}}
    assert kept_model(feature) == "least-squares feature, NARX(p=40, q=40, c=0)"
    assert kept_model({"kept": "arx", "linear_orders": {"arx": {"p": 3, "q": 10}}}) == "ARX(3, 10)"
    assert kept_model({"kept": "network"}) == kept_model({}) == "network"
