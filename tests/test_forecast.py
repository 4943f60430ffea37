"""k-step-ahead forecasts: forecast[:, t, j] predicts y_{t+j} from y_{<t}; j = 0 is predict; NaN past T."""

import dataclasses

import numpy as np
import pytest
import torch

from mop.config import RunConfig, SystemConfig, apply_overrides
from mop.errors import MopError
from mop.predictors import PREDICTORS, forecast, is_learned, make_predictor
from mop.systems import FAMILIES
from mop.systems.base import Trajectories

K = 4


def generate(family: str, n: int = 3, horizon: int = 24, seed: int = 0, **knobs) -> Trajectories:
    fam = FAMILIES.get(family)(SystemConfig(family=family, **knobs))
    return fam.generate(n, horizon, generator=torch.Generator().manual_seed(seed))


@pytest.fixture(scope="module")
def tiny_recurrent(tmp_path_factory) -> dict:
    """{predictor name: a tiny trained run} of each recurrent architecture (gru, deep-lru)."""
    from mop.train import train

    runs = {}
    for arch in ("gru", "deep-lru"):
        cfg = apply_overrides(
            RunConfig(),
            [
                "system.output_dim=2",
                "system.state_dim=2",
                f"model.arch={arch}",
                "model.num_layers=1",
                "model.width=16",
                "model.context=10",
                "train.steps=5",
                "train.horizon=10",
            ],
        )
        runs[arch] = train(cfg, tmp_path_factory.mktemp(arch) / "tiny", progress=False)
    return runs


def numpy_kalman_priors(A, C, Q, R, P0, y):
    """Plain numpy KF (one system): prior means / covariances of x_t given y_{<t}, t = 0..T."""
    m, P = np.zeros(A.shape[0]), P0.copy()
    means, covs = [], []
    for yt in y:
        means.append(m.copy())
        covs.append(P.copy())
        S = C @ P @ C.T + R
        Kg = P @ C.T @ np.linalg.inv(S)
        m = m + Kg @ (yt - C @ m)
        P = (np.eye(len(m)) - Kg @ C) @ P
        m, P = A @ m, A @ P @ A.T + Q
    return means, covs


def numpy_switching_forecast(p, b, y, s, K):
    """Independent forecasts of one switching system b: a numpy KF with the time-varying model
    (A_t, C_t) = (A, C) for t < s, (A2, C2) from s on; mean[t, k] = C_{t+k} A_{t+k-1} ... A_t m_t from the
    prior m_t given y_<t (NaN past T)."""
    A1, C1, A2, C2, Q, R, P0 = (M[b].double().numpy() for M in (p.A, p.C, p.A2, p.C2, p.Q, p.R, p.P0))
    A_at, C_at = (lambda t: A2 if t >= s else A1), (lambda t: C2 if t >= s else C1)
    T1, m, P = len(y), np.zeros(A1.shape[0]), P0.copy()
    out = np.full((T1, K, C1.shape[0]), np.nan)
    for t in range(T1):
        x = m.copy()
        for k in range(K):
            if t + k < T1:
                out[t, k] = C_at(t + k) @ x
            x = A_at(t + k) @ x
        C = C_at(t)
        S = C @ P @ C.T + R
        gain = P @ C.T @ np.linalg.inv(S)
        m, P = m + gain @ (y[t] - C @ m), (np.eye(len(m)) - gain @ C) @ P
        m, P = A_at(t) @ m, A_at(t) @ P @ A_at(t).T + Q
    return out


def test_kalman_forecast_equals_C_A_power_prior_and_its_covariance():
    traj = generate("linear")
    mean, var = make_predictor("kalman").forecast_distribution(traj, K)
    T = traj.horizon
    for b in range(traj.num_systems):
        p = traj.params
        A, C, Q, R, P0 = (M[b].double().numpy() for M in (p.A, p.C, p.Q, p.R, p.P0))
        means, covs = numpy_kalman_priors(A, C, Q, R, P0, traj.y[b].double().numpy())
        for t in (0, 1, 7, T - 2):
            for k in range(K):
                if t + k > T:
                    assert torch.isnan(mean[b, t, k]).all()
                    continue
                Ak = np.linalg.matrix_power(A, k)
                expected = C @ Ak @ means[t]
                Pk = Ak @ covs[t] @ Ak.T + sum(
                    np.linalg.matrix_power(A, i) @ Q @ np.linalg.matrix_power(A, i).T for i in range(k)
                )
                np.testing.assert_allclose(mean[b, t, k].numpy(), expected, rtol=1e-4, atol=1e-5)
                np.testing.assert_allclose(
                    var[b, t, k].numpy(), np.diag(C @ Pk @ C.T + R), rtol=1e-4, atol=1e-6
                )


def test_rollout_of_a_perfect_one_step_predictor_is_exact():
    """Noiseless linear system, KF with Q = R ~ 0: once x is known the k-step forecast is exact."""
    traj = generate("linear", n=2, horizon=30, noise_var_w=0.0, noise_var_v=0.0)
    p = traj.params
    B, n = p.A.shape[:2]
    Q = 1e-12 * torch.eye(n, dtype=p.Q.dtype).expand(B, n, n).clone()
    R = 1e-10 * torch.eye(p.C.shape[1], dtype=p.R.dtype).expand_as(p.R).clone()
    traj = dataclasses.replace(traj, params=dataclasses.replace(p, Q=Q, R=R))
    f = forecast(make_predictor("kalman"), traj, 6)
    for j in range(6):
        err = (f[:, 10 : traj.horizon + 1 - j, j] - traj.y[:, 10 + j :]).abs().max()
        assert err < 1e-4 * traj.y[:, 10:].abs().max(), (j, err)
    assert (f[:, 10:20, 5] - f[:, 10:20, 0]).abs().max() > 1e-2  # the horizons differ


def test_rls_rollout_is_exact_on_a_noiseless_ar2():
    """y_t = a1 y_{t-1} + a2 y_{t-2} (undamped, so y does not die out): after RLS has identified
    the recursion its k-step roll-out is exact."""
    T, a1, a2 = 80, 2 * np.cos(0.3), -1.0
    y = torch.zeros(1, T + 1, 1, dtype=torch.float64)
    y[0, 0, 0], y[0, 1, 0] = 100.0, 30.0  # large: RLS's ridge prior (P_0 = I) then biases theta by ~1e-6
    for t in range(2, T + 1):
        y[0, t] = a1 * y[0, t - 1] + a2 * y[0, t - 2]
    traj = Trajectories(y=y)
    f = forecast(make_predictor("rls"), traj, 8)
    for j in range(8):
        err = (f[0, 40 : T + 1 - j, j] - y[0, 40 + j :]).abs().max()
        assert err < 1e-3 * y.abs().max(), (j, err)  # a wrong roll-out misses by ~1e2
    assert y[0, 40:].abs().max() > 50
    assert (f[0, 5:, 3] - f[0, 5:, 0]).abs().nansum() > 0  # the horizons differ (not a copy of j = 0)


BAYES_FAMILY = SystemConfig(family="linear-inputs", state_dim=1, output_dim=1, input_dim=1)


def _trajectory_for(name: str, tiny_run) -> Trajectories:
    if is_learned(name):
        return generate("linear", n=2, horizon=14, output_dim=2, state_dim=2)  # 14 > context 10
    if name == "bayes":  # the Bayes mixture needs a time-invariant family: one of few unknowns
        return generate("linear-inputs", n=2, horizon=14, state_dim=1, output_dim=1, input_dim=1)
    return generate("switching", n=2, horizon=14, switch_time=6)


@pytest.mark.parametrize("name", PREDICTORS.names())
def test_every_forecast_is_causal_and_starts_at_predict(name, tiny_run, tiny_recurrent):
    """forecast[:, t, j] uses y_<t only: changing y_s for s >= 7 changes no forecast from an origin
    t <= 7 (an independent check for every predictor, including those whose forecast repeats predict);
    j = 0 is the one-step prediction; NaN exactly where t + j > T."""
    run_dir = {"mop": tiny_run, **tiny_recurrent}.get(name)
    options = {"run_dir": run_dir, "num_particles": 50, "seed": 0, "system": BAYES_FAMILY}
    traj = _trajectory_for(name, tiny_run)
    f = forecast(make_predictor(name, shared=options), traj, K)
    T = traj.horizon
    assert f.shape == (traj.num_systems, T + 1, K, traj.output_dim)
    later = traj.select(slice(None))
    later.y = traj.y.clone()
    later.y[:, 7:] += 2.0
    f_later = forecast(make_predictor(name, shared=options), later, K)
    torch.testing.assert_close(f_later[:, :8], f[:, :8], rtol=1e-5, atol=1e-6, equal_nan=True)
    assert (f_later[:, 9:, 0] - f[:, 9:, 0]).abs().max() > 1e-3 or name == "zero"  # the data is used
    torch.testing.assert_close(
        f[:, :, 0], make_predictor(name, shared=options).predict(traj), rtol=1e-5, atol=1e-6
    )
    for j in range(1, K):
        assert torch.isnan(f[:, T + 1 - j :, j]).all() and torch.isfinite(f[:, : T + 1 - j, j]).all()


def test_kf_ekf_and_ukf_forecasts_across_a_switch_equal_a_numpy_kalman_filter():
    """On a (linear, time-varying) switching family the KF, the EKF and the UKF are the same filter; each
    one's forecast, across the switch at t = 9, against the numpy roll-out of the true model."""
    traj = generate("switching", switch_time=9)
    for name in ("kalman", "ekf", "ukf"):
        f = forecast(make_predictor(name), traj, 6)
        for b in range(traj.num_systems):
            ref = numpy_switching_forecast(traj.params, b, traj.y[b].double().numpy(), 9, 6)
            np.testing.assert_allclose(f[b].double().numpy(), ref, rtol=1e-4, atol=1e-5, err_msg=name)


def test_kalman_system1_forecast_keeps_system_1_after_the_switch():
    """Independent: the numpy KF of system 1 alone (a "switch" that never comes), forecasts past t = 9."""
    traj = generate("switching", switch_time=9)
    f = forecast(make_predictor("kalman-system1"), traj, 5)
    for b in range(traj.num_systems):
        ref = numpy_switching_forecast(traj.params, b, traj.y[b].double().numpy(), 10**9, 5)
        np.testing.assert_allclose(f[b].double().numpy(), ref, rtol=1e-4, atol=1e-5)
    truth = numpy_switching_forecast(traj.params, 0, traj.y[0].double().numpy(), 9, 5)
    assert np.nanmax(np.abs(f[0, 12:].double().numpy() - truth[12:])) > 1e-2  # system 2 is not used


def test_quadrotor_ekf_forecast_steps_through_f_with_the_inputs():
    """Independent roll-out of the EKF mean: j steps of project(f(project(m), u)) from the prior at t."""
    from mop.filters.gaussian import ekf_step, gaussian_filter
    from mop.systems.base import state_space_of

    traj = generate("quadrotor", n=2, horizon=12)
    model = state_space_of(traj)
    priors = {}
    gaussian_filter(
        model, ekf_step, traj.y.double(), traj.u.double(), at_prior=lambda t, m, P, _: priors.setdefault(t, m)
    )
    f = forecast(make_predictor("ekf"), traj, 4)
    t = 5
    m = priors[t]
    for j in range(1, 4):
        x = model.project(m)
        m = model.project(model.f(x[:, None], traj.u.double()[:, t + j - 1, None], t + j - 1)[:, 0])
        torch.testing.assert_close(f[:, t, j], (model.C @ m[..., None])[..., 0].to(f.dtype))


def test_learned_forecast_rolls_out_on_its_own_predictions(tiny_run):
    """Independent: feed the model [y_0..y_{t-1}, yhat_t, yhat_{t+1}] (last C) and read the last output."""
    from mop.runs import load_model

    model, cfg = load_model(tiny_run)
    traj = generate("linear", n=2, horizon=14, output_dim=2, state_dim=2)
    f = forecast(make_predictor("mop", run_dir=tiny_run), traj, 3)
    y = traj.y.float()
    with torch.no_grad():
        for t in (0, 3, 9, 11):
            seq = y[:, :t]
            for j in range(1, 3):
                seq = torch.cat([seq, f[:, t, j - 1, None].float()], dim=1)
                out = model(seq[:, -cfg.context :])[:, -1]
                torch.testing.assert_close(f[:, t, j].float(), out, rtol=1e-5, atol=1e-5)


def test_forecast_helper_refuses_predictors_without_one_and_bad_steps():
    class OneStep:
        name = "one-step"

        def predict(self, traj):
            return traj.y

    traj = generate("linear", n=1, horizon=5)
    with pytest.raises(MopError, match="one-step.*no k-step forecast"):
        forecast(OneStep(), traj, 2)
    with pytest.raises(MopError, match="steps"):
        forecast(make_predictor("last"), traj, 0)
    with pytest.raises(MopError, match=r"forecast start must be an integer origin in \[0, T = 5\], got 6"):
        forecast(make_predictor("last"), traj, 2, start=6)


@pytest.mark.parametrize("name", PREDICTORS.names())
def test_forecast_from_a_start_origin_equals_the_full_forecast_there(name, tiny_run, tiny_recurrent):
    """forecast(..., start=s): NaN for origins t < s and, from s on, the full forecast's values (for the
    particle filter, which skips the earlier roll-outs, exactly: each origin draws from its own generator)."""
    run_dir = {"mop": tiny_run, **tiny_recurrent}.get(name)
    options = {"run_dir": run_dir, "num_particles": 50, "seed": 0, "system": BAYES_FAMILY}
    traj = _trajectory_for(name, tiny_run)
    full = forecast(make_predictor(name, shared=options), traj, K)
    part = forecast(make_predictor(name, shared=options), traj, K, start=6)
    assert torch.isnan(part[:, :6]).all()
    assert torch.equal(torch.isnan(part[:, 6:]), torch.isnan(full[:, 6:]))
    torch.testing.assert_close(part[:, 6:], full[:, 6:], rtol=0, atol=0, equal_nan=True)
