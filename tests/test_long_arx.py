"""The records recipe's longer ARX orders (mop.identify.long_arx): chosen by held-out free-run simulation
where a long record supports them, with training windows long enough for the feature, and budgeted."""

import math

import numpy as np
import pytest

from mop.identify.cubic import simulate_narx
from mop.identify.long_arx import LONG_ORDERS, choose_long_orders
from mop.recipe.budget import NOMINAL_HORIZON, NOMINAL_STEP_SECONDS, plan_steps
from mop.recipe.layers import training_config
from mop.recipe.records import feature_line, order_line
from mop.recipe.source import check_init

pytestmark = pytest.mark.usefixtures("one_thread")


def delayed_plant(steps: int, delay: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """y_{t+1} = 0.7 y_t + u_{t - delay + 1} + e: an input delay of `delay` steps, which an ARX(p, q)
    predicts exactly only with q >= delay input lags (u_t..u_{t-q+1})."""
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(steps, 1))
    y = np.zeros((steps, 1))
    for t in range(steps - 1):
        y[t + 1] = 0.7 * y[t] + (u[t - delay + 1] if t >= delay - 1 else 0) + 0.05 * rng.normal()
    return y, u


def write(path, y, u):
    rows = "\n".join(f"{a:.8f},{b:.8f}" for a, b in zip(y[:, 0], u[:, 0], strict=True))
    path.write_text("y0,u0\n" + rows + "\n")
    return path


def test_a_delay_beyond_the_short_orders_takes_the_shortest_long_order_that_holds_it():
    y, u = delayed_plant(6000, delay=18)
    p, q, scores = choose_long_orders([(y, u)], 2, 10)
    assert (p, q) == (20, 20)  # 15 input lags cannot hold u_{t-17}; 20 can, and 30 adds nothing
    assert scores["20,20"] < 0.2 * scores["2,10"] and scores["15,15"] > 3 * scores["20,20"]
    # the score is the least-squares fit's simulation of the held-out fifth: noise-level for the true order
    assert scores["20,20"] < 0.1


def test_a_plant_the_short_orders_hold_keeps_them():
    y, u = delayed_plant(6000, delay=2)
    p, q, scores = choose_long_orders([(y, u)], 1, 2)
    assert (p, q) == (1, 2) and set(scores) == {"1,2", *(f"{P},{P}" for P in LONG_ORDERS)}


def test_a_short_record_or_one_without_inputs_keeps_the_orders_and_tries_nothing():
    y, u = delayed_plant(1024, delay=18)
    assert choose_long_orders([(y, u)], 2, 10) == (2, 10, {})
    y, u = delayed_plant(6000, delay=18)
    assert choose_long_orders([(y, u[:, :0])], 4, 0) == (4, 0, {})


def test_the_scores_are_the_held_out_simulation_of_the_least_squares_fit():
    from mop.filters.arx import least_squares_coefficients

    y, u = delayed_plant(6000, delay=18)
    _, _, scores = choose_long_orders([(y, u)], 2, 10)
    cut = 6000 - math.ceil(0.2 * 6000)
    theta = least_squares_coefficients([np.concatenate([y[:cut], u[:cut]], 1)], 1, 20, 20, True)
    sim = simulate_narx(theta, y[cut - 20 :], u[cut - 20 :], 20, 20, 0, 20)
    assert scores["20,20"] == pytest.approx(float(np.sqrt(np.mean((sim - y[cut:]) ** 2))), rel=1e-9)


def test_the_recipe_trains_a_long_feature_on_windows_twice_its_orders_and_budgets_them(tmp_path):
    y, u = delayed_plant(8000, delay=26)
    rec = write(tmp_path / "rec.csv", y, u)
    config = training_config(None, None, str(rec), overrides=["model.arch=gpt"], budget=1)  # it reads it
    m = config.model
    assert (m.rls_order, m.arx_order, m.rls_cubes, m.rls_fixed) == (30, 30, 0, True)
    assert config.train.horizon == 60 and m.context == 60
    windows = 7200 - 60  # the training part (the last 10% validates), windows of 61 steps
    assert config.train.steps == plan_steps(1, windows, 64, 60).steps
    assert "longer than `mop fit arx`" in order_line(config, [])
    assert "ARX(30, 30) with an intercept one-step prediction fixed at its least-squares fit" in feature_line(
        config
    )


def test_longer_windows_buy_proportionally_fewer_steps():
    short, long = plan_steps(5, 10**6, 64), plan_steps(5, 10**6, 64, 2 * NOMINAL_HORIZON)
    assert short.steps == int(5 * 60 / NOMINAL_STEP_SECONDS) and long.steps == short.steps // 2
    assert plan_steps(5, 10**6, 64, 30).steps == short.steps  # shorter windows are not cheaper


def test_orders_above_max_order_are_not_tried():
    y, u = delayed_plant(6000, delay=18)
    p, q, scores = choose_long_orders([(y, u)], 2, 10, max_order=15)
    assert (p, q) == (2, 10) or (p, q) == (15, 15)
    assert set(scores) == {"2,10", "15,15"}


def test_a_fine_tuned_class_model_reads_the_long_order_a_long_record_needs(tmp_path):
    y, u = delayed_plant(6000, delay=18)
    rec = write(tmp_path / "rec.csv", y, u)
    config = training_config(None, None, str(rec), init="pretrained:lti-siso")
    m = config.model
    assert (m.rls_order, m.arx_order, m.rls_prior, m.rls_fixed) == (20, 20, "fit", True)
    check_init(config)  # the fixed feature is the source's network with another prior: it may fine-tune
    assert "longer than `mop fit arx" in order_line(config, [], init="pretrained:lti-siso")


@pytest.mark.parametrize("gaps", [False, True])
def test_a_fixed_feature_is_the_recursion_whose_p0_vanishes_and_the_fitted_arxs_prediction(gaps):
    """model.rls_fixed (P_0 = 0) skips the recursion: it equals the step-by-step recursion from P_0 =
    1e-300 (no pair can move theta) to rounding, and the ARX's own predictions computed independently in
    numpy: one step ahead on complete outputs, the free run (mop.identify.cubic.simulate_narx) where the
    outputs after the first 50 are missing."""
    import torch

    from mop.filters.arx import arx_predict, least_squares_coefficients
    from mop.identify.cubic import regressor_rows

    y, u = delayed_plant(1500, delay=18)
    theta = least_squares_coefficients([np.concatenate([y, u], 1)], 1, 20, 20, True)
    yt, ut = torch.from_numpy(y)[None].clone(), torch.from_numpy(u)[None]
    if gaps:
        yt[:, 50:] = float("nan")
    fast = arx_predict(yt, ut, 20, 20, True, (torch.from_numpy(theta), 0.0), bounded=0)[0].numpy()
    slow = arx_predict(yt, ut, 20, 20, True, (torch.from_numpy(theta), 1e-300), bounded=0)[0].numpy()
    np.testing.assert_allclose(fast, slow, rtol=1e-12, atol=1e-12)
    if gaps:
        np.testing.assert_allclose(fast[50:], simulate_narx(theta, y, u, 20, 20, 0, 50), rtol=1e-9, atol=1e-9)
    else:
        one_step = regressor_rows(y, u, 20, 20, 0) @ theta  # row t predicts y_{t+1}
        np.testing.assert_allclose(fast[21:], one_step[20:-1], rtol=1e-9, atol=1e-9)


def test_a_fixed_feature_needs_coefficients_to_stay_at(tmp_path, capsys):
    from mop.cli import main

    rec = write(tmp_path / "rec.csv", *delayed_plant(600, delay=2))
    code = main(
        [
            "train",
            "--data",
            str(rec),
            "--out",
            str(tmp_path / "run"),
            "model.rls_order=2",
            "model.rls_fixed=true",
        ]
    )
    err = capsys.readouterr().err.strip()
    assert code != 0 and "model.rls_fixed" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "run").exists()
