"""Fitted identifiers (mop.identify): ARX against a plain numpy least-squares fit and a known system's
coefficients, N4SID against mop.filters.subspace and nfoursid (Markov parameters C A^j B), simulation of a
known system against ARX's, order selection on known orders, the predictor conventions (causality, forecast
vs predict vs simulate) and the save / load round trip."""

import numpy as np
import pandas as pd
import pytest
import torch
from nfoursid.nfoursid import NFourSID

from mop.errors import MopError
from mop.filters.subspace import identify_with_inputs
from mop.identify import fit, load, save
from mop.identify.arx import ARX
from mop.identify.n4sid import N4SID
from mop.systems.base import Trajectories


def markov(A, B, C, num=6):
    """[C B, C A B, ..., C A^{num-1} B]: invariant under a change of state basis."""
    out, AjB = [], B
    for _ in range(num):
        out.append(C @ AjB)
        AjB = A @ AjB
    return np.stack(out)


def state_space(N, noise, rng, offset=0.0):
    """A known 3-state SISO system with well-separated modes (0.85, 0.7 +- 0.5j), white input, output noise:
    (y with noise (N, 1), u (N, 1), noise-free y (N, 1))."""
    A = np.zeros((3, 3))
    A[0, 0], A[1:, 1:] = 0.85, [[0.7, 0.5], [-0.5, 0.7]]
    B, C = np.array([[1.0], [0.5], [1.0]]), np.array([[1.0, 1.0, 0.5]])
    u, x, ys = rng.normal(size=(N, 1)), np.zeros(3), []
    for t in range(N):
        ys.append(C @ x)
        x = A @ x + B @ u[t]
    y = np.array(ys) + offset
    return y + noise * rng.normal(size=y.shape), u, y, (A, B, C)


def arx_record(N, rng, sigma=0.1, lengths=None):
    """Trajectories of a known MIMO ARX(2, 1) system (m = 2, k = 1) with an intercept and equation noise."""
    a1, a2 = np.array([[0.5, 0.2], [-0.1, 0.4]]), np.array([[-0.2, 0.0], [0.1, -0.1]])
    b1, c = np.array([[1.0], [-0.5]]), np.array([0.3, -0.2])
    data = []
    for n in lengths or [N]:
        u, y = rng.normal(size=(n, 1)), np.zeros((n, 2))
        for t in range(2, n):
            y[t] = a1 @ y[t - 1] + a2 @ y[t - 2] + b1 @ u[t - 1] + c + sigma * rng.normal(size=2)
        data.append((y, u))
    return data, np.concatenate([a1, a2, b1], axis=1), c


def traj(y, u):
    return Trajectories(y=torch.from_numpy(y)[None], u=None if u is None else torch.from_numpy(u)[None])


def test_arx_fit_equals_a_plain_numpy_least_squares_fit():
    """Coefficients, one-step predictions and a free-run simulation against the normal equations and the
    recursion written out over t and trajectories."""
    data, _, _ = arx_record(0, np.random.default_rng(0), lengths=[120, 80, 95])
    p, q = 3, 2
    rows, targets = [], []
    for y, u in data:
        for t in range(3, len(y)):
            rows.append(np.concatenate([y[t - 1], y[t - 2], y[t - 3], u[t - 1], u[t - 2], [1.0]]))
            targets.append(y[t])
    Phi, Y = np.array(rows), np.array(targets)
    theta = np.linalg.solve(Phi.T @ Phi, Phi.T @ Y)  # (3*2 + 2*1 + 1, 2)
    fitted = ARX.fit_grid(data, [{"p": p, "q": q}], {}, 3)[0]
    np.testing.assert_allclose(fitted.model.C, theta[:-1].T, atol=1e-10)
    np.testing.assert_allclose(fitted.model.d, theta[-1], atol=1e-10)
    y, u = data[1]
    yhat = fitted.predict(traj(y, u))[0].numpy()
    lag = lambda a, t, j: a[max(t - j, 0)]  # noqa: E731 (before the record: its first values)
    for t in range(1, len(y)):
        phi = np.concatenate([lag(y, t, 1), lag(y, t, 2), lag(y, t, 3), lag(u, t, 1), lag(u, t, 2), [1.0]])
        np.testing.assert_allclose(yhat[t], theta.T @ phi, atol=1e-10)
    context, sim = 10, y.copy()  # free run: the model's own outputs replace y from the context on
    for t in range(context, len(y)):
        sim[t] = theta.T @ np.concatenate([sim[t - 1], sim[t - 2], sim[t - 3], u[t - 1], u[t - 2], [1.0]])
    np.testing.assert_allclose(fitted.simulate(traj(y, u), context)[0].numpy(), sim[context:], atol=1e-10)


def test_arx_recovers_a_known_systems_coefficients_within_its_standard_errors():
    rng = np.random.default_rng(1)
    sigma = 0.1
    data, truth, c = arx_record(20000, rng, sigma)
    fitted = ARX.fit_grid(data, [{"p": 2, "q": 1}], {}, 2)[0]
    y, u = data[0]
    Phi = np.concatenate([y[1:-1], y[:-2], u[1:-1], np.ones((len(y) - 2, 1))], axis=1)
    se = sigma * np.sqrt(np.diag(np.linalg.inv(Phi.T @ Phi)))  # standard error of each coefficient
    err = np.concatenate([fitted.model.C - truth, (fitted.model.d - c)[:, None]], axis=1)  # (m, d)
    assert (np.abs(err) < 5 * se[None]).all(), (err / se).round(1)


def test_arx_order_selection_finds_the_systems_orders():
    data, _, _ = arx_record(0, np.random.default_rng(2), sigma=0.1, lengths=[400, 400])
    for select in ("simulation", "one-step"):
        assert fit("arx", data, select, max_order=4).orders == {"p": 2, "q": 1}


def test_n4sid_on_one_trajectory_equals_identify_with_inputs():
    """The multi-trajectory fit on a single trajectory is mop.filters.subspace's algorithm on mean-removed
    data."""
    y, u, _, _ = state_space(500, 0.1, np.random.default_rng(3), offset=2.0)
    fitted = N4SID.fit_grid([(y, u)], [{"n": 3}], {}, 3)[0]  # block rows ceil(3 / 1) + 1 = 4
    yc, uc = y - y.mean(0), u - u.mean(0)
    A, B, C, _ = (
        M[0].numpy()
        for M in identify_with_inputs(torch.from_numpy(yc)[None], torch.from_numpy(uc)[None], 3, 4)
    )
    M = fitted.model
    np.testing.assert_allclose(markov(M.A, M.B, M.C), markov(A, B, C), atol=1e-8)


def nfoursid_markov(y, u, order, i):
    df = pd.DataFrame(np.concatenate([y, u], axis=1), columns=["y0", "u0"])
    sid = NFourSID(df, output_columns=["y0"], input_columns=["u0"], num_block_rows=i)
    sid.subspace_identification()
    ss, _ = sid.system_identification(rank=order)
    return markov(ss.a, ss.b, ss.c)


def test_n4sid_markov_parameters_agree_with_nfoursid_and_the_truth():
    y, u, _, (A, B, C) = state_space(3000, 0.1, np.random.default_rng(4))
    fitted = N4SID.fit_grid([(y, u)], [{"n": 3}], {}, 3)[0]
    mine = markov(fitted.model.A, fitted.model.B, fitted.model.C)
    ref = nfoursid_markov(y - y.mean(0), u - u.mean(0), 3, 4)
    scale = np.abs(markov(A, B, C)).max()
    assert np.abs(mine - ref).max() < 0.05 * scale
    assert np.abs(mine - markov(A, B, C)).max() < 0.05 * scale


def test_n4sid_picks_the_true_order_and_simulates_a_validation_record_better_than_arx():
    """Output noise (an output-error system): ARX's equation-error fit is biased, N4SID's is not."""
    rng = np.random.default_rng(5)
    ye, ue, _, _ = state_space(600, 0.2, rng, offset=1.0)
    yv, uv, clean, _ = state_space(400, 0.2, rng, offset=1.0)
    n4sid, arx = fit("n4sid", [(ye, ue)], max_order=6), fit("arx", [(ye, ue)], max_order=6)
    assert n4sid.orders["n"] == 3
    rmse = lambda f: np.sqrt(((f.simulate(traj(yv, uv), 20)[0].numpy() - clean[20:]) ** 2).mean())  # noqa: E731
    assert rmse(n4sid) < 0.7 * rmse(arx), (rmse(n4sid), rmse(arx))
    assert rmse(n4sid) < 0.1 * clean.std()


@pytest.mark.parametrize("context", [0, 3, 40])
def test_noise_free_n4sid_simulates_exactly_after_a_context_that_sees_the_state(context):
    """The initial state fitted by least squares to the context outputs (context 0: the first outputs); three
    outputs determine the three states of this observable system."""
    rng = np.random.default_rng(6)
    y, u, _, _ = state_space(300, 0.0, rng, offset=0.5)
    fitted = fit("n4sid", [(y, u)], max_order=4)
    assert fitted.orders["n"] == 3
    yv, uv, _, _ = state_space(80, 0.0, rng, offset=0.5)
    yv, uv = yv[30:], uv[30:]  # a record that does not start at rest
    sim = fitted.simulate(traj(yv, uv), context)[0].numpy()
    assert sim.shape == (len(yv) - context, 1)
    np.testing.assert_allclose(sim, yv[context:], atol=1e-3 * yv.std())


@pytest.mark.parametrize("kind", ["arx", "n4sid"])
@pytest.mark.parametrize("inputs", [True, False])
def test_predictor_conventions(kind, inputs):
    """predict = forecast[..., 0]; yhat_t reads y_<t only; simulate after C reads y_<C only; ARX's simulate
    after C is its forecast from origin C (its state is the measured lags)."""
    rng = np.random.default_rng(7)
    y, u, _, _ = state_space(300, 0.1, rng, offset=1.0)
    u = u if inputs else None
    fitted = fit(kind, [(y, u)], max_order=3)
    tr = traj(y[:60], None if u is None else u[:60])
    yhat, fc = fitted.predict(tr), fitted.forecast(tr, 4)
    torch.testing.assert_close(fc[..., 0, :], yhat)
    changed = traj(y[:60].copy(), None if u is None else u[:60])
    changed.y[0, 30:] += 5.0
    torch.testing.assert_close(fitted.predict(changed)[:, :31], yhat[:, :31])
    torch.testing.assert_close(fitted.simulate(changed, 30), fitted.simulate(tr, 30))
    if kind == "arx":
        torch.testing.assert_close(fitted.simulate(tr, 30)[:, :4], fc[:, 30])


@pytest.mark.parametrize("kind", ["arx", "n4sid"])
def test_save_load_round_trip_gives_identical_predictions(kind, tmp_path):
    rng = np.random.default_rng(8)
    data, _, _ = arx_record(0, rng, lengths=[150, 120])
    fitted = fit(kind, data, max_order=3, source="est.csv")
    save(fitted, tmp_path / "model")
    again = load(tmp_path / "model")
    assert (again.kind, again.orders, again.info) == (fitted.kind, fitted.orders, fitted.info)
    assert again.info["estimation"] == "est.csv" and len(again.info["grid"]) == (9 if kind == "arx" else 3)
    tr = traj(*data[1])
    torch.testing.assert_close(again.predict(tr), fitted.predict(tr), rtol=0, atol=0)
    torch.testing.assert_close(again.forecast(tr, 3), fitted.forecast(tr, 3), rtol=0, atol=0, equal_nan=True)
    torch.testing.assert_close(again.simulate(tr, 10), fitted.simulate(tr, 10), rtol=0, atol=0)


def test_bad_records_are_refused_in_one_line():
    rng = np.random.default_rng(9)
    data, _, _ = arx_record(0, rng, lengths=[40])
    with pytest.raises(MopError, match=r"too few to fit arx orders up to 10; use --max-order \d"):
        fit("arx", data)
    with pytest.raises(MopError, match="too few to fit n4sid orders up to 10; use --max-order"):
        fit("n4sid", data)
    y, u = data[0]
    y = y.copy()
    y[5, 0] = np.nan
    with pytest.raises(MopError, match="1 output.* missing"):
        fit("arx", [(y, u)], max_order=2)
    with pytest.raises(MopError, match="--select"):
        fit("arx", data, select="aic", max_order=2)
    fitted = fit("arx", data, max_order=2)
    with pytest.raises(MopError, match="fitted on 2 output"):
        fitted.predict(traj(y[:, :1], u))
