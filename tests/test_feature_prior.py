"""model.rls_prior: the RLS / ARX feature started from fitted coefficients. Against plain least squares
written here, the fixed-ARX closed form where P_0 -> 0, the ridge closed form of the recursion, and streaming
equal to the forward."""

import numpy as np
import pytest
import torch

from mop.config import DataConfig, ModelConfig
from mop.errors import MopError
from mop.filters.arx import arx_predict
from mop.models import build_model
from mop.models.predict import stream
from mop.train.records import read_recorded


def tiny(**kw) -> ModelConfig:
    base = dict(num_layers=1, num_heads=2, width=16, context=30, input_dim=2, output_dim=1)
    return ModelConfig(**{**base, "rls_order": 2, "arx_order": 2, "rls_offset": True, **kw})


def arx_record(T: int = 3000, seed: int = 0, noise: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """y_{t+1} = 1.2 y_t - 0.5 y_{t-1} + 0.7 u_t + 0.2 u_{t-1} + 0.3 + e: coefficients in the order of
    mop.filters.arx's regressors [y_t, y_{t-1}, u_t, u_{t-1}, 1]."""
    rng = np.random.default_rng(seed)
    u, y = rng.normal(size=T), np.zeros(T)
    for t in range(1, T - 1):
        y[t + 1] = 1.2 * y[t] - 0.5 * y[t - 1] + 0.7 * u[t] + 0.2 * u[t - 1] + 0.3 + noise * rng.normal()
    return y, u


TRUE = np.array([1.2, -0.5, 0.7, 0.2, 0.3])


def write(path, y, u):
    lines = ["trajectory,t,y0,u0"] + [
        f"r,{t},{float(a)!r},{float(b)!r}" for t, (a, b) in enumerate(zip(y, u, strict=True))
    ]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_fit_prior_is_least_squares_in_normalised_units(tmp_path):
    y, u = arx_record()
    rec = read_recorded(DataConfig(path=str(write(tmp_path / "r.csv", y, u))))
    cfg = DataConfig(path="r.csv", **rec.fit())
    theta = np.array(rec.fit_prior(cfg, 2, 2, True))
    # numpy least squares on the same training steps, normalised by the fitted mean / std
    n = len(rec.train_parts[0])
    yn = (y[:n] - cfg.y_mean[0]) / cfg.y_std[0]
    un = (u[:n] - cfg.u_mean[0]) / cfg.u_std[0]
    X = np.stack([yn[1:-1], yn[:-2], un[1:-1], un[:-2], np.ones(n - 2)], axis=1)
    ref = np.linalg.lstsq(X, yn[2:], rcond=None)[0]
    np.testing.assert_allclose(theta, ref, rtol=1e-4, atol=1e-5)
    # and back in the record's units it is the system's ARX equation (noise 0.01: within 0.01)
    sy, su = cfg.y_std[0], cfg.u_std[0]
    a1, a2, b1, b2, c = theta
    c_units = sy * c + cfg.y_mean[0] * (1 - a1 - a2) - sy / su * (b1 + b2) * cfg.u_mean[0]
    np.testing.assert_allclose([a1, a2, b1 * sy / su, b2 * sy / su, c_units], TRUE, atol=0.01)


def test_a_tight_prior_makes_the_feature_the_fixed_arx():
    """P_0 -> 0: the recursion never moves, so r_{t+1} = theta_0^T phi_t after the start-up (t >= r)."""
    y, u = arx_record(T=60)
    yt, ut = torch.tensor(y)[None, :, None], torch.tensor(u)[None, :, None]
    pred = arx_predict(yt, ut, 2, 2, offset=True, prior=(torch.tensor(TRUE)[:, None], 1e-12))[0, :, 0].numpy()
    fixed = 1.2 * y[1:-1] - 0.5 * y[:-2] + 0.7 * u[1:-1] + 0.2 * u[:-2] + 0.3  # predicts y_2..y_{T-1}
    np.testing.assert_allclose(pred[3:], fixed[1:], rtol=1e-9, atol=1e-9)
    assert np.abs(pred[3:] - y[3:]).max() < 0.05  # noise 0.01: the fixed ARX predicts well


def test_the_prior_is_the_ridge_solution_around_theta_0():
    """RLS from (theta_0, p0 I) is (I / p0 + sum phi phi^T)^-1 (theta_0 / p0 + sum phi y), at the end."""
    y, u = arx_record(T=40, noise=0.3)
    theta0, p0 = torch.tensor([0.5, 0.1, 0.2, 0.0, 0.1])[:, None].double(), 0.05
    yt, ut = torch.tensor(y)[None, :, None], torch.tensor(u)[None, :, None]
    pred = arx_predict(yt, ut, 2, 2, offset=True, prior=(theta0, p0))[0, -1, 0].item()
    X = np.stack([y[1:-2], y[:-3], u[1:-2], u[:-3], np.ones(len(y) - 3)], axis=1)  # pairs up to y_{T-2}
    theta = np.linalg.solve(np.eye(5) / p0 + X.T @ X, theta0.numpy()[:, 0] / p0 + X.T @ y[2:-1])
    phi_last = np.array([y[-2], y[-3], u[-2], u[-3], 1.0])
    assert pred == pytest.approx(phi_last @ theta, rel=1e-9)


def test_model_with_a_prior_starts_as_it_and_streams_equal_to_the_forward():
    model = build_model(tiny(rls_prior=[0.9, -0.2, 0.5, 0.1, 0.05])).double().eval()
    g = torch.Generator().manual_seed(0)
    z = torch.randn(3, 30, 2, generator=g, dtype=torch.float64)
    expect = arx_predict(
        z[..., :1],
        z[..., 1:],
        2,
        2,
        True,
        (torch.tensor([[0.9], [-0.2], [0.5], [0.1], [0.05]], dtype=torch.float64), 1e-3),
    )
    with torch.no_grad():
        torch.testing.assert_close(model(z[:, :-1]), expect[:, 1:], rtol=1e-10, atol=1e-10)
        for p in model.parameters():
            p.normal_(0.0, 0.3)
        torch.testing.assert_close(stream(model, z)[0], model(z), rtol=1e-9, atol=1e-9)


def test_prior_errors():
    with pytest.raises(MopError, match="holds 3 rows of coefficients, the feature reads 5"):
        build_model(tiny(rls_prior=[1.0, 2.0, 3.0]))
    with pytest.raises(MopError, match="needs model.rls_order > 0"):
        build_model(tiny(rls_order=0, arx_order=0, rls_offset=False, rls_prior="fit"))
    with pytest.raises(MopError, match="'none', 'fit', 'family', 'mixture' or a list"):
        build_model(tiny(rls_prior="fitted"))


def test_a_class_model_with_a_prior_runs_it_in_the_data_units_across_gaps_and_streams_alike():
    """A class model (record_norm, observation mask) given a listed prior (a fine-tune's model.rls_prior=fit):
    at initialisation it is mop.filters.arx's recursion from that prior on the data as given (not in the
    record's frame, where fitted coefficients do not hold), outputs missing from step 15 on (a free-run
    simulation: each missing output filled with the feature's own prediction), and streaming it equals its
    forward. Over the start-up (t <= r = 2, where the recursion holds y_{t-1}) it predicts by the prior from
    the first values (features.fitted_start): yhat_1 = theta . [y_0, y_0, u_0, u_0, 1], yhat_2 = theta .
    [y_1, y_0, u_1, u_0, 1]; the fit is the recursion's, so from t = 3 on the two agree."""
    theta = [0.9, -0.2, 0.5, 0.1, 0.05]
    cfg = tiny(rls_prior=theta, record_norm="causal", observation_mask=True, input_dim=3)
    model = build_model(cfg).double().eval()
    g = torch.Generator().manual_seed(1)
    z = torch.randn(3, 30, 2, generator=g, dtype=torch.float64) * 4.0 + 7.0  # far from the record frame
    y = z[..., :1].clone()
    y[:, 15:] = float("nan")
    prior = (torch.tensor(theta, dtype=torch.float64)[:, None], 1e-3)
    expect = arx_predict(y, z[..., 1:], 2, 2, True, prior)  # (3, 30, 1): expect[:, t] predicts y_t
    y0, u0, y1, u1 = z[:, 0, 0], z[:, 0, 1], z[:, 1, 0], z[:, 1, 1]
    one = torch.ones_like(y0)
    expect[:, 1, 0] = torch.stack([y0, y0, u0, u0, one], -1) @ prior[0][:, 0]
    expect[:, 2, 0] = torch.stack([y1, y0, u1, u0, one], -1) @ prior[0][:, 0]
    seen = ~torch.isnan(y)
    inputs = torch.cat([torch.where(seen, y, torch.zeros_like(y)), z[..., 1:], seen.double()], dim=-1)
    with torch.no_grad():
        torch.testing.assert_close(model(inputs[:, :-1]), expect[:, 1:], rtol=1e-10, atol=1e-10)
        for p in model.parameters():
            p.normal_(0.0, 0.3)
        torch.testing.assert_close(stream(model, inputs)[0], model(inputs), rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("order", [(2, 2), (4, 3), (10, 10)])
def test_a_fine_tuned_class_model_simulates_from_the_start_as_the_fitted_arx(order):
    """With its fitted coefficients held (P_0 -> 0), a class model's feature is mop.identify.arx's fitted
    ARX (lags before the record's start at its first values, an independent implementation): one step
    ahead on a complete record, and simulated from y_0 alone (`mop predict --simulate 0`: y_1.. missing),
    before and after r = max(p, q). Breaking fitted_start (the recursion's hold of y_{t-1} for t <= r)
    fails both. ARX(10, 10), the class models' orders: the start's r assumed values are not measured
    outputs, so they set no fill bounds (mop.filters.rls.fill_bounds; counted, they held the simulation at
    y_0)."""
    from mop.identify.arx import arx_model
    from mop.identify.linear import FittedPredictor
    from mop.systems.trajectories import Trajectories

    p, q = order
    rng = np.random.default_rng(3)
    ar, exo = np.zeros(p), np.zeros(q)
    ar[: min(p, 4)], exo[: min(q, 3)] = [0.9, -0.3, 0.1, -0.05][:p], [0.5, 0.2, -0.1][:q]
    theta = np.concatenate([ar, exo, [0.2]])
    cfg = tiny(
        rls_order=p,
        arx_order=q,
        rls_prior=theta.tolist(),
        rls_prior_cov=(1e-12 * np.eye(p + q + 1)).ravel().tolist(),
        record_norm="causal",
        observation_mask=True,
        input_dim=3,
    )
    model = build_model(cfg).double().eval()
    y, u = arx_record(T=30, seed=4)
    y, u = y + 2.0, u + rng.normal(size=30) * 0.1  # not at rest at step 0
    fitted = FittedPredictor(
        "arx",
        {"p": p, "q": q},
        arx_model(theta[:, None], p, q, np.zeros(1), np.zeros(1)),
        1,
        1,
        lag_state=True,
    )
    traj = Trajectories(torch.tensor(y)[None, :, None], torch.tensor(u)[None, :, None])
    one_step, simulated = fitted.predict(traj)[0, 1:, 0], fitted.simulate(traj, 1)[0, :, 0]
    ones = torch.ones(1, 30, 1, dtype=torch.float64)
    inputs = torch.cat([torch.tensor(y)[None, :, None], torch.tensor(u)[None, :, None], ones], -1)
    with torch.no_grad():
        torch.testing.assert_close(model(inputs[:, :-1])[0, :, 0], one_step, rtol=1e-8, atol=1e-8)
        free = inputs.clone()
        free[:, 1:, 0], free[:, 1:, 2] = 0.0, 0.0  # y_1..y_T missing
        torch.testing.assert_close(model(free[:, :-1])[0, :, 0], simulated, rtol=1e-8, atol=1e-8)
        torch.testing.assert_close(stream(model, free)[0][0, :-1, 0], simulated, rtol=1e-8, atol=1e-8)
