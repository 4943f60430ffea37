"""The cubic NARX feature (model.rls_cubes) and the records recipe's choice of it (mop.identify.cubic)."""

import math

import numpy as np
import pytest
import torch

from mop.filters.arx import arx_predict, arx_regressors
from mop.identify.cubic import choose_cubes, fit_narx, regressor_rows, simulate_narx
from mop.predictors import make_predictor
from mop.systems.base import Trajectories


def duffing(steps: int, seed: int, noise: float = 0.0, cubic: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """A discretised Duffing oscillator as a cubic NARX: y_{t+1} = 1.6 y_t - 0.8 y_{t-1} - cubic y_t^3
    + 0.1 u_t (+ output noise), u ~ N(0, 1); bounded also when driven twice as hard."""
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(steps, 1))
    y = np.zeros((steps, 1))
    for t in range(1, steps - 1):
        y[t + 1] = 1.6 * y[t] - 0.8 * y[t - 1] - cubic * y[t] ** 3 + 0.1 * u[t]
    return y + noise * rng.normal(size=y.shape), u


def test_the_features_regressors_are_the_lags_their_cubes_the_input_lags_and_the_constant():
    y, u = duffing(30, 0)
    y2 = np.concatenate([y, -2 * y], axis=1)  # two outputs: the cubes of each channel's lags
    torch_rows = arx_regressors(torch.tensor(y2)[None], torch.tensor(u)[None], 3, 2, True, cubes=2)[0].numpy()
    t = 10
    lags = [y2[t], y2[t - 1], y2[t - 2]]
    expected = np.concatenate([*lags, lags[0] ** 3, lags[1] ** 3, u[t], u[t - 1], [1.0]])
    np.testing.assert_allclose(torch_rows[t], expected)
    np.testing.assert_allclose(torch_rows, regressor_rows(y2, u, 3, 2, 2))


def test_the_in_context_recursion_with_cubes_is_the_ridge_solution_of_its_pairs():
    """Closed form: with theta_0 = 0 and P_0 = I the recursion's prediction of y_t is phi_{t-1}^T theta,
    theta = (I + sum phi_{s-1} phi_{s-1}^T)^-1 sum phi_{s-1} y_s over the pairs r <= s < t (r = 2)."""
    y, u = duffing(200, 1)
    yhat = arx_predict(torch.tensor(y)[None], torch.tensor(u)[None], 2, 1, cubes=2)[0].numpy()
    phi = regressor_rows(y, u, 2, 1, 2)[:, :-1]  # no constant: offset off
    for t in (5, 60, 199):
        rows, targets = phi[1 : t - 1], y[2:t]  # (phi_{s-1}, y_s), s = 2..t-1
        theta = np.linalg.solve(np.eye(phi.shape[1]) + rows.T @ rows, rows.T @ targets)
        np.testing.assert_allclose(yhat[t], phi[t - 1] @ theta, rtol=1e-9, atol=1e-12)


def test_least_squares_recovers_the_plant_and_simulates_it():
    y, u = duffing(2000, 2)
    theta = fit_narx([(y, u)], 2, 1, 1)
    np.testing.assert_allclose(theta[:, 0], [1.6, -0.8, -0.1, 0.1, 0.0], atol=1e-5)
    sim = simulate_narx(theta, y, u, 2, 1, 1, 10)
    np.testing.assert_allclose(sim, y[10:], atol=1e-4 * np.abs(y).max())


def test_a_blown_up_simulation_is_nan_from_where_it_left_the_range():
    y, u = duffing(300, 3)
    theta = fit_narx([(y, u)], 2, 1, 1)
    theta[2] = 1.0  # a cubic term of the wrong sign: the free run escapes
    sim = simulate_narx(theta, y, 5 * u, 2, 1, 1, 10)
    assert np.isnan(sim[-1]).all() and np.isfinite(sim[0]).all()


@pytest.mark.parametrize("seed", range(5))
def test_the_choice_is_cubic_on_a_cubic_plant_and_linear_on_a_linear_one(seed):
    """Statistical: on 5 seeds each, a noisy cubic plant gets cubed lags and simulates its held-out tail at
    under half the best linear candidate's RMSE (observed 0.26-0.42); the same plant without its cubic term
    keeps the ARX (c = 0)."""
    y, u = duffing(1500, seed, noise=0.01)
    p, c, scores = choose_cubes([(y, u)], 2, 1)
    linear = min(scores[f"{pp},0"] for pp in range(2, 6))
    assert c >= 1 and scores[f"{p},{c}"] < 0.5 * linear
    y, u = duffing(1500, seed, noise=0.01, cubic=0.0)
    p, c, scores = choose_cubes([(y, u)], 2, 1)
    assert (p, c) == (2, 0)


def test_a_cubic_candidate_that_blows_up_when_driven_harder_is_not_kept(monkeypatch):
    """The stress check: the cubic plant's own model escapes when its input is 30 times larger (a discrete
    cubic map's free run is bounded only on its amplitudes), so with STRESS = 30 no cubic candidate is
    kept."""
    import mop.identify.cubic as cubic

    y, u = duffing(1500, 0, noise=0.01)
    assert choose_cubes([(y, u)], 2, 1)[1] >= 1
    theta = fit_narx([(y, u)], 2, 1, 1)
    assert np.isnan(simulate_narx(theta, y, 30 * u, 2, 1, 1, 10)).any()
    monkeypatch.setattr(cubic, "STRESS", 30.0)
    p, c, scores = choose_cubes([(y, u)], 2, 1)
    assert (p, c) == (2, 0) and all(math.isinf(v) for k, v in scores.items() if not k.endswith(",0"))


def test_the_narx_baseline_identifies_a_cubic_plant_in_context_and_simulates_it():
    """narx-10-cubes-10-offset-ls (the feature the duffing class model reads, as a predictor): on a
    noise-free plant of its model class, 400 outputs of context identify it, and its free run of the next
    599 steps matches the record (measured max error 4e-6 of the output range: P_0 = 1e4 I is a ridge of
    1e-4); the ARX(10, 10) without
    the cubes cannot (error above 1% of the range)."""
    y, u = duffing(1000, 0)
    traj = Trajectories(torch.from_numpy(y)[None], torch.from_numpy(u)[None])
    span = float(np.ptp(y))
    sim = make_predictor("narx-10-cubes-10-offset-ls").simulate(traj, 400)[0].numpy()
    assert np.abs(sim - y[400:]).max() < 1e-4 * span
    linear = make_predictor("arx-10-offset-ls").simulate(traj, 400)[0].numpy()
    assert np.abs(linear - y[400:]).max() > 1e-2 * span
