"""The family's empirical-Bayes prior of the RLS / ARX feature (mop.train.auto.family_prior, rls_prior_cov):
against numpy least squares system by system, against the distribution a synthetic family's coefficients are
drawn from, the recursion from a matrix P_0 against its closed form, and the prior's effect on the online
identifier (a short record predicted better than from theta_0 = 0, P_0 = I)."""

import numpy as np
import pytest
import torch

from mop.errors import MopError
from mop.filters.arx import arx_predict
from mop.models import build_model
from mop.models.predict import stream
from mop.train import auto
from tests.test_feature_prior import tiny

MEAN, STD, NOISE = np.array([0.5, 1.0]), np.array([0.2, 0.3]), 0.1


def family(num: int, horizon: int, seed: int) -> tuple[torch.Tensor, torch.Tensor, np.ndarray]:
    """y_{t+1} = a_i y_t + b_i u_t + 0.1 e_t, (a_i, b_i) ~ N(MEAN, diag(STD^2)) per system, u ~ N(0, 1):
    y, u (N, T+1, 1) and the coefficients (N, 2), in the ARX(1, 1) regressor order [y_t, u_t]."""
    rng = np.random.default_rng(seed)
    coef = MEAN + STD * rng.normal(size=(num, 2))
    coef[:, 0] = np.clip(coef[:, 0], -0.95, 0.95)  # stable
    u = rng.normal(size=(num, horizon + 1))
    y = np.zeros((num, horizon + 1))
    for t in range(horizon):
        y[:, t + 1] = coef[:, 0] * y[:, t] + coef[:, 1] * u[:, t] + NOISE * rng.normal(size=num)
    return torch.tensor(y)[..., None], torch.tensor(u)[..., None], coef


def test_prior_is_the_mean_and_covariance_of_each_systems_least_squares():
    y, u, _ = family(40, 30, seed=0)
    theta0, P0 = auto.family_prior(y, u, 2, 2)
    yn, un = y[..., 0].numpy(), u[..., 0].numpy()
    fits, residuals = [], []
    for yi, ui in zip(yn, un, strict=True):  # pairs (phi_{s-1}, y_s), s >= 2: phi_{s-1} = [y, y, u, u] lags
        X = np.stack([yi[1:-1], yi[:-2], ui[1:-1], ui[:-2]], axis=1)
        coef = np.linalg.lstsq(X, yi[2:], rcond=None)[0]
        fits.append(coef)
        residuals.append(yi[2:] - X @ coef)
    fits = np.array(fits)
    sigma2 = np.mean(np.square(residuals))
    cov = np.cov(fits.T, bias=True) / sigma2
    np.testing.assert_allclose(theta0[:, 0].numpy(), fits.mean(0), rtol=1e-6, atol=1e-8)
    ridge = auto.PRIOR_RIDGE * np.trace(cov) / 4 * np.eye(4)
    np.testing.assert_allclose(P0.numpy(), cov + ridge, rtol=1e-5, atol=1e-9)


def test_prior_recovers_the_distribution_the_coefficients_are_drawn_from():
    """4000 systems of 400 steps: theta_0 within 4 standard errors of MEAN, and sigma^2 P_0 the coefficients'
    covariance diag(STD^2) within 10% (each system's own least-squares error adds ~NOISE^2 / 400 / var)."""
    y, u, coef = family(4000, 400, seed=1)
    theta0, P0 = auto.family_prior(y, u, 1, 1)
    se = coef.std(0) / np.sqrt(len(coef))
    assert np.all(np.abs(theta0[:, 0].numpy() - MEAN) < 4 * se + 1e-3)
    cov = P0.numpy() * NOISE**2
    np.testing.assert_allclose(np.diag(cov), coef.var(0), rtol=0.1)
    assert abs(cov[0, 1]) < 0.1 * np.sqrt(cov[0, 0] * cov[1, 1])  # drawn independently


def test_recursion_from_a_matrix_p0_is_the_posterior_mean():
    """theta_T = (P_0^-1 + X^T X)^-1 (P_0^-1 theta_0 + X^T y): the Gaussian-prior posterior mean."""
    y, u, _ = family(1, 25, seed=2)
    g = np.random.default_rng(3)
    L = g.normal(size=(2, 2))
    P0 = L @ L.T + 0.1 * np.eye(2)
    theta0 = np.array([0.3, 0.8])
    prior = (torch.tensor(theta0)[:, None], torch.tensor(P0))
    pred = arx_predict(y, u, 1, 1, prior=prior)[0, -1, 0].item()
    yn, un = y[0, :, 0].numpy(), u[0, :, 0].numpy()
    X = np.stack([yn[:-2], un[:-2]], axis=1)  # the pairs (phi_{s-1}, y_s) up to y_{T-1}
    Pi = np.linalg.inv(P0)
    theta = np.linalg.solve(Pi + X.T @ X, Pi @ theta0 + X.T @ yn[1:-1])
    assert pred == pytest.approx(np.array([yn[-2], un[-2]]) @ theta, rel=1e-9)


def test_the_family_prior_predicts_short_records_better():
    """On new systems of the family, 15 steps each, the ARX(1, 1) recursion from the family's prior has a
    lower one-step MSE over t >= 3 than from theta_0 = 0, P_0 = I (by over 20% here), and over the last
    steps (t >= 10) too: the prior is the family's, not a guess."""
    fit_y, fit_u, _ = family(512, 200, seed=4)
    y, u, _ = family(2000, 15, seed=5)
    prior = auto.family_prior(fit_y, fit_u, 1, 1)
    for start in (3, 10):
        with_prior = auto.identifier_error(y, u, 1, 1, start, prior)
        without = auto.identifier_error(y, u, 1, 1, start, None)
        assert with_prior < (0.8 if start == 3 else 1.0) * without


def test_model_with_a_matrix_prior_starts_as_it_and_streams_equal_to_the_forward():
    theta = [0.9, -0.2, 0.5, 0.1, 0.05]
    cov = (np.eye(5) * 0.5 + 0.1).flatten().tolist()
    model = build_model(tiny(rls_prior=theta, rls_prior_cov=cov)).double().eval()
    z = torch.randn(3, 30, 2, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    f64 = dict(dtype=torch.float64)
    prior = (torch.tensor(theta, **f64)[:, None], torch.tensor(cov, **f64).reshape(5, 5))
    expect = arx_predict(z[..., :1], z[..., 1:], 2, 2, True, prior)
    with torch.no_grad():
        torch.testing.assert_close(model(z[:, :-1]), expect[:, 1:], rtol=1e-10, atol=1e-10)
        for p in model.parameters():
            p.normal_(0.0, 0.3)
        torch.testing.assert_close(stream(model, z)[0], model(z), rtol=1e-9, atol=1e-9)


def test_matrix_prior_errors():
    with pytest.raises(MopError, match="5 x 5 = 25 numbers"):
        build_model(tiny(rls_prior=[0.9, -0.2, 0.5, 0.1, 0.05], rls_prior_cov=[1.0, 0.0]))
    with pytest.raises(MopError, match="beside a list model.rls_prior"):
        build_model(tiny(rls_prior_cov=[1.0] * 25))


def test_given_orders_with_the_family_prior_equal_what_auto_resolves():
    """model.rls_prior=family with the orders auto picks gives auto's model keys (one prior, two routes)."""
    from mop.experiments import get_experiment, run_config

    exp = get_experiment("linear-inputs")
    resolved = run_config(exp, "smoke", overrides=["model.features=auto"]).model
    assert resolved.rls_prior_cov is not None
    given = run_config(
        exp,
        "smoke",
        overrides=[
            f"model.rls_order={resolved.rls_order}",
            f"model.arx_order={resolved.arx_order}",
            "model.rls_prior=family",
        ],
    ).model
    assert (given.rls_prior, given.rls_prior_cov) == (resolved.rls_prior, resolved.rls_prior_cov)


def test_family_prior_on_recorded_data_is_a_one_line_error():
    import dataclasses

    from mop.config import DataConfig, RunConfig, apply_overrides

    config = apply_overrides(RunConfig(), ["model.rls_order=2", "model.rls_prior=family"])
    config = dataclasses.replace(config, data=DataConfig(path="x.csv"))
    with pytest.raises(MopError, match="on recorded data use model.rls_prior=fit"):
        auto.resolve_features(config)
