"""model.features = "auto" (mop.train.auto): the rule against processes of known order and scale, the step
budget's closed form, and the resolved run against the run of the same keys written out (same config, same
weights)."""

import dataclasses
import json

import pytest
import torch

from mop.checkpoint import load_tensors
from mop.config import RunConfig, apply_overrides, to_dict
from mop.errors import MopError
from mop.experiments import get_experiment, run_config
from mop.experiments.planning import config_hash
from mop.train import auto, train


def ar_data(num: int, horizon: int, seed: int, lag: int = 3, input_lag: int | None = None):
    """y_{t+1} = 0.9 y_{t+1-lag} (+ u_{t-input_lag}) + 0.1 e: the output order is `lag`, the input order
    input_lag + 1 (the regressors u_t..u_{t-q+1}); y (N, T+1, 2), u (N, T+1, 1) or None."""
    g = torch.Generator().manual_seed(seed)
    y = torch.zeros(num, horizon + 1, 2, dtype=torch.float64)
    u = None if input_lag is None else torch.randn(num, horizon + 1, 1, generator=g, dtype=torch.float64)
    y[:, :lag] = torch.randn(num, lag, 2, generator=g, dtype=torch.float64)
    for t in range(lag - 1, horizon):
        y[:, t + 1] = 0.9 * y[:, t + 1 - lag] + 0.1 * torch.randn(num, 2, generator=g, dtype=torch.float64)
        if u is not None and t >= input_lag:
            y[:, t + 1] += u[:, t - input_lag]
    return y, u


def orders(choice: auto.FeatureChoice) -> tuple[bool, int, int]:
    return choice.scale, choice.order, choice.input_order


def test_output_only_data_gets_rls_ar_of_its_order():
    """No inputs: RLS-AR(p) with p the process's own order (3; AR(1), AR(2) cannot represent it)."""
    y, _ = ar_data(256, 50, seed=0, lag=3)
    fit = ar_data(256, 200, seed=10, lag=3)
    choice = auto.choose_features(y, None, fit)
    assert orders(choice) == (False, 3, 0)
    assert choice.prior_theta == () == choice.prior_cov  # output-only: the paper's start (module docstring)


def test_data_with_inputs_gets_arx_with_the_input_lags_it_needs():
    """u_{t-2} drives y_{t+1}: ARX with q = 3 input regressors (u_t, u_{t-1}, u_{t-2}); the output lag 1."""
    y, u = ar_data(256, 50, seed=1, lag=1, input_lag=2)
    fit = ar_data(256, 200, seed=11, lag=1, input_lag=2)
    choice = auto.choose_features(y, u, fit)
    assert orders(choice) == (False, 1, 3)
    assert len(choice.prior_theta) == 2 * (1 * 2 + 3 * 1) and len(choice.prior_cov) == 5 * 5  # m = 2, k = 1


def test_running_scale_where_outputs_are_far_from_unit_scale():
    y, _ = ar_data(256, 50, seed=2, lag=2)
    assert not auto.scale_far_from_unit(y)
    assert auto.scale_far_from_unit(100 * y)  # the median RMS far from 1
    spread = torch.logspace(-1.5, 1.5, 256, dtype=torch.float64)[:, None, None]  # sizes over 3 decades
    assert auto.scale_far_from_unit(y * spread)
    assert auto.choose_features(y * spread, None, (y * spread, None)).scale


def test_training_that_drops_outputs_gets_no_identifier():
    y, u = ar_data(64, 50, seed=3, lag=1, input_lag=0)
    assert auto.choose_features(y, u, (y, u), drops_outputs=True) == auto.FeatureChoice()


@pytest.mark.parametrize(
    ("choice", "steps", "expected"),
    [
        (auto.FeatureChoice(), 2500, 2500),
        (auto.FeatureChoice(order=2, input_order=2), 2500, 2100),  # the quadrotor's hand-made budget
        (auto.FeatureChoice(scale=True, order=3), 2500, 2100),  # 2500 / (1.04 * 1.17) = 2056
        (auto.FeatureChoice(scale=True), 2500, 2400),
        (auto.FeatureChoice(order=1), 30, 26),
    ],
)
def test_steps_follow_the_step_cost(choice, steps, expected):
    """steps / cost to two significant digits, cost the product of the STEP_COST factors."""
    assert auto.steps_for(steps, choice.cost) == expected
    scale = auto.STEP_COST["scale"] if choice.scale else 1.0
    assert choice.cost == pytest.approx(scale * (auto.STEP_COST["identifier"] if choice.order else 1.0))


def test_resolved_run_config_equals_the_explicit_keys():
    """linear-inputs under auto: the same RunConfig (and hash, so the same run directory) as its chosen keys
    written out; a layer naming a feature key takes the keys as given (no auto, no step scaling)."""
    exp = get_experiment("linear-inputs")
    resolved = run_config(exp, "smoke", overrides=["model.features=auto"])
    m = resolved.model
    assert m.features == "given" and m.rls_order > 0 and m.arx_order > 0
    keys = [
        f"model.rls_order={m.rls_order}",
        f"model.arx_order={m.arx_order}",
        f'model.input_scale="{m.input_scale}"',  # JSON: the string "none", not null
        f"model.rls_prior={json.dumps(m.rls_prior)}",  # the family's prior (test_family_prior.py)
        f"model.rls_prior_cov={json.dumps(m.rls_prior_cov)}",
    ]
    explicit = run_config(exp, "smoke", overrides=[*keys, f"train.steps={resolved.train.steps}"])
    assert resolved == explicit and config_hash(resolved) == config_hash(explicit)
    auto_preset = dataclasses.replace(exp, presets={"smoke": {"model.features": "auto"}})
    assert run_config(auto_preset, "smoke") == resolved
    given = run_config(auto_preset, "smoke", overrides=["model.rls_order=2"])  # a later layer's key wins
    assert (given.model.rls_order, given.model.arx_order, given.train.steps) == (2, 0, 30)
    literal = run_config(auto_preset, "smoke", overrides=["train.steps=40"])  # the user's steps as given
    assert literal.model == resolved.model and literal.train.steps == 40
    scaled = run_config(dataclasses.replace(auto_preset, train={**exp.train, "train.steps": 40}), "smoke")
    assert scaled.train.steps == auto.steps_for(40, auto.STEP_COST["identifier"])  # an experiment's budget


def test_gru_reads_no_features():
    config = run_config(get_experiment("linear-inputs"), "smoke", overrides=["model.features=auto"])
    gru = auto.for_arch(config, "gru")
    assert gru.model.arch == "gru" and (gru.model.rls_order, gru.model.arx_order) == (0, 0)


def test_auto_run_trains_the_same_weights_as_the_explicit_run(tmp_path, one_thread):
    """mop.train.train on a config with model.features=auto (resolved by the trainer) == the run of the
    keys it chose: identical config.json and identical weights."""
    base = [
        "system.family=linear-inputs",
        "model.num_layers=1",
        "model.width=16",
        "model.num_heads=2",
        "model.context=20",
        "train.horizon=20",
        "train.batch_size=4",
        "train.checkpoint_every=100",
    ]
    auto_cfg = apply_overrides(RunConfig(), [*base, "model.features=auto", "train.steps=12"])
    chosen = auto.resolve_features(auto_cfg)
    m = chosen.model
    assert m.rls_order > 0 and chosen.train.steps == auto.steps_for(12, auto.STEP_COST["identifier"])
    keys = [
        f"model.rls_order={m.rls_order}",
        f"model.arx_order={m.arx_order}",
        f"model.rls_prior={json.dumps(m.rls_prior)}",
        f"model.rls_prior_cov={json.dumps(m.rls_prior_cov)}",
        f"train.steps={chosen.train.steps}",
    ]
    explicit_cfg = apply_overrides(RunConfig(), [*base, *keys])
    a, b = (
        train(auto_cfg, tmp_path / "auto", progress=False),
        train(explicit_cfg, tmp_path / "explicit", progress=False),
    )
    saved = [json.loads((run / "config.json").read_text()) for run in (a, b)]
    assert saved[0] == saved[1] and saved[0]["model"]["rls_order"] == m.rls_order
    assert "features" not in saved[0]["model"]  # resolved: the saved config holds the keys
    wa, wb = (load_tensors(run / "model.safetensors")[0] for run in (a, b))
    assert wa.keys() == wb.keys() and all(torch.equal(wa[k], wb[k]) for k in wa)


def test_bad_features_value_is_one_line_error():
    with pytest.raises(MopError, match="model.features must be 'given' or 'auto'"):
        apply_overrides(RunConfig(), ["model.features=yes"])


def test_describe_features():
    model = dataclasses.replace(RunConfig().model, input_scale="running", rls_order=3)
    assert auto.describe_features(model) == "running scale + RLS-AR(3)"
    assert auto.describe_features(dataclasses.replace(model, input_scale="none", arx_order=2)) == "ARX(3, 2)"
    assert auto.describe_features(RunConfig().model) == "none"
    assert "features" not in to_dict(RunConfig())["model"]  # omitted at its default: old hashes unchanged


def test_mop_train_plan_line_names_the_chosen_features(one_thread):
    """The line `mop train` prints before training names what auto chose (and nothing for a plain model)."""
    from mop.models import build_model
    from mop.train import resolve_config
    from mop.train.estimate import plan_line

    base = ["system.family=linear-inputs", "model.num_layers=1", "model.width=16", "model.num_heads=2"]
    base += ["model.context=20", "train.horizon=20", "train.batch_size=4", "train.steps=12"]
    for extra, words in ((["model.features=auto"], "features ARX("), ([], "(gpt 1 x 16);")):
        config = resolve_config(apply_overrides(RunConfig(), [*base, *extra]))
        line = plan_line(config, build_model(config.model), torch.device("cpu"))
        assert words in line, line
