"""The ARX feature under a mixture-of-Gaussians prior (mop.filters.mixture): against the exact Bayesian
posterior computed by scipy, the single-prior recursion, its own closed form, EM on known clusters, the
model's stream, and auto's choice."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.special import logsumexp
from scipy.stats import multivariate_normal
from torch import Tensor

from mop.config import DataConfig, ModelConfig, RunConfig, SystemConfig, from_dict
from mop.errors import MopError
from mop.experiments.files import import_plugin
from mop.filters.arx import arx_predict, arx_regressors
from mop.filters.mixture import MixturePrior, fit_mixture, mixture_predict
from mop.models import build_model
from mop.models.features import feature_prior
from mop.models.predict import stream
from mop.systems import generator, make_family
from mop.train.auto import MIXTURE_GAIN, MIXTURE_SIZE, describe_features, identifier_error, resolve_features

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
F64 = torch.float64


def data(B=4, T=24, m=2, k=1, seed=0):
    g = torch.Generator().manual_seed(seed)
    return torch.randn(B, T, m, generator=g, dtype=F64), torch.randn(B, T, k, generator=g, dtype=F64)


def random_prior(K, d, m, noise=0.3, seed=1) -> MixturePrior:
    g = torch.Generator().manual_seed(seed)
    A = torch.randn(K, d, d, generator=g, dtype=F64)
    covs = A @ A.mT / d + 0.5 * torch.eye(d, dtype=F64)
    weights = torch.rand(K, generator=g, dtype=F64) + 0.2
    return MixturePrior(weights / weights.sum(), torch.randn(K, d, m, generator=g, dtype=F64), covs, noise)


def test_one_component_is_the_single_prior_recursion():
    y, u = data()
    p, q = 2, 3
    prior = random_prior(1, p * 2 + q, 2)
    expect = arx_predict(y, u, p, q, False, (prior.means[0], prior.covs[0]))
    torch.testing.assert_close(mixture_predict(y, u, p, q, prior), expect, rtol=0, atol=1e-12)


def test_prediction_is_the_exact_posterior_mean_scipy():
    """At each t: weights w_k ~ pi_k N(Y; X mu_k, sigma^2 (I + X P_k X^T)) (scipy's multivariate normal,
    per output column), each component's posterior mean by the normal equations, and
    yhat = sum_k w_k theta_k^T phi."""
    y, u = data(B=2, T=16, m=2)
    p, q, K, noise = 2, 2, 3, 0.3
    d = p * 2 + q
    prior = random_prior(K, d, 2, noise)
    yhat = mixture_predict(y, u, p, q, prior).numpy()
    phi = arx_regressors(y, u, p, q).numpy()
    r = max(p, q)
    for b in range(2):
        for t in (r + 1, r + 4, 15):
            X, Y = phi[b, r - 1 : t - 1], y[b, r:t].numpy()  # the pairs (phi_{s-1}, y_s), s = r..t-1
            logw, means = [], []
            for k in range(K):
                mu, P = prior.means[k].numpy(), prior.covs[k].numpy()
                cov = noise * (np.eye(len(X)) + X @ P @ X.T)
                logw.append(
                    np.log(prior.weights[k].item())
                    + sum(multivariate_normal(X @ mu[:, j], cov).logpdf(Y[:, j]) for j in range(2))
                )
                prec = np.linalg.inv(P) + X.T @ X
                means.append(np.linalg.solve(prec, np.linalg.inv(P) @ mu + X.T @ Y))
            w = np.exp(np.array(logw) - logsumexp(logw))
            expect = sum(w[k] * means[k].T @ phi[b, t - 1] for k in range(K))
            np.testing.assert_allclose(yhat[b, t], expect, rtol=1e-9, atol=1e-11)
    # the start-up: yhat_0 = 0, yhat_t = y_{t-1} up to r
    np.testing.assert_array_equal(yhat[:, 0], 0)
    np.testing.assert_array_equal(yhat[:, 1 : r + 1], y[:, :r].numpy())


def closed_form_mixture_predict(y: Tensor, u: Tensor, p: int, q: int, prior: MixturePrior) -> Tensor:
    """mixture_predict's yhat (B, T, m) for complete y (B, T, m) and u (B, T, k), all steps at once in
    information form: the pairs' sums S_t = sum phi phi^T and b_t = sum phi y^T shared by the components,
    Lambda = P_k^-1 + S_t, theta = Lambda^-1 (P_k^-1 mu_k + b_t), and the evidence
    log N(Y; X mu_k, sigma^2 (I + X P_k X^T)) per output column, the product of the recursion's one-step
    densities. A reference for the tests, not a path mop runs: its batched Cholesky factorisations of B T K
    small matrices took 186 against 65 ms for mixture_predict's loop (B = 64, T = 51, K = 8, d = 12)."""
    B, T, m = y.shape
    r = max(p, q)
    phi = arx_regressors(y, u, p, q)  # (B, T, d)
    head = torch.cat([y.new_zeros(B, 1, m), y[:, :r]], dim=1)  # yhat_0 = 0, yhat_t = y_{t-1} up to r
    X, Y = phi[:, r - 1 : T - 2], y[:, r : T - 1]  # the pairs (phi_{s-1}, y_s), s = r..T-2
    S = torch.cumsum(X[..., :, None] * X[..., None, :], dim=1)  # (B, n, d, d)
    b = torch.cumsum(X[..., :, None] * Y[..., None, :], dim=1)  # (B, n, d, m)
    yy = torch.cumsum(Y.pow(2).sum(-1), dim=1)  # (B, n)
    prior_prec = torch.linalg.inv(prior.covs)  # (K, d, d)
    prior_b = prior_prec @ prior.means  # (K, d, m)
    L = torch.linalg.cholesky(prior_prec + S[:, :, None])  # (B, n, K, d, d)
    theta = torch.cholesky_solve(prior_b + b[:, :, None], L)  # (B, n, K, d, m): the posterior means
    quad = (prior.means * prior_b).sum((-2, -1)) - (theta * (prior_b + b[:, :, None])).sum((-2, -1))
    logdet = 2 * L.diagonal(dim1=-2, dim2=-1).log().sum(-1) + torch.logdet(prior.covs)  # log det(P_k Lambda)
    log_w = prior.weights.log() - 0.5 * ((yy[..., None] + quad) / prior.noise + m * logdet)  # (B, n, K)
    each = (theta.mT @ phi[:, r : T - 1, None, :, None])[..., 0]  # (B, n, K, m): yhat_{r+1+i}
    return torch.cat([head, (torch.softmax(log_w, -1)[..., None] * each).sum(2)], dim=1)


def test_recursion_equals_its_closed_form():
    y, u = data(B=3, T=30, m=1, k=2)
    prior = random_prior(4, 3 + 2 * 4, 1)
    closed = closed_form_mixture_predict(y, u, 3, 4, prior)
    torch.testing.assert_close(mixture_predict(y, u, 3, 4, prior), closed, rtol=1e-9, atol=1e-10)


def test_em_recovers_two_known_clusters():
    g = torch.Generator().manual_seed(3)
    d, m, N = 3, 2, 3000
    centres = torch.tensor([[2.0, 0.0, -1.0], [-2.0, 1.0, 1.0]], dtype=F64)[..., None].expand(2, d, m)
    first = torch.rand(N, generator=g) < 0.3
    theta = torch.where(first[:, None, None], centres[0], centres[1])
    theta = theta + 0.2 * torch.randn(N, d, m, generator=g, dtype=F64)
    prior = fit_mixture(theta, noise=0.5, size=2)
    k = int(prior.means[:, 0, 0].argmax())  # the component at +2
    assert abs(prior.weights[k].item() - first.double().mean().item()) < 0.01
    torch.testing.assert_close(prior.means[k], centres[0], atol=0.02, rtol=0)
    torch.testing.assert_close(prior.means[1 - k], centres[1], atol=0.02, rtol=0)
    # the covariance, in noise units: 0.04 I / 0.5 (plus the small floor)
    torch.testing.assert_close(prior.covs[k].diagonal(), torch.full((d,), 0.08, dtype=F64), atol=0.01, rtol=0)


def mixture_model(**kw) -> ModelConfig:
    prior = random_prior(3, 2 * 2 + 2 * 1, 2)
    base = dict(num_layers=2, num_heads=2, width=16, context=20, input_dim=3, output_dim=2)
    keys = dict(
        rls_order=2,
        arx_order=2,
        rls_prior=prior.means.flatten().tolist(),
        rls_prior_cov=prior.covs.flatten().tolist(),
        rls_prior_weights=prior.weights.tolist(),
        rls_prior_noise=prior.noise,
    )
    return ModelConfig(**{**base, **keys, **kw})


def test_model_with_a_mixture_prior_starts_as_it_and_streams_equal_to_the_forward():
    cfg = mixture_model()
    y, u = data(B=3, T=21, m=2, k=1)
    z = torch.cat([y, u], -1)
    model = build_model(cfg).double().eval()
    with torch.no_grad():
        expect = mixture_predict(y, u, 2, 2, random_prior(3, 6, 2))[:, 1:]
        torch.testing.assert_close(model(z[:, :-1]), expect, rtol=1e-12, atol=1e-12)  # zero read-out
        for prm in model.parameters():
            prm.normal_(0.0, 0.3)
        torch.testing.assert_close(stream(model, z[:, :-1])[0], model(z[:, :-1]), rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"rls_prior_weights": [0.5, 0.2, 0.1]}, "summing to 1"),
        ({"rls_prior_weights": [0.5, 0.5]}, "rows of coefficients"),
        ({"rls_offset": True}, "without model.rls_offset"),
        ({"observation_mask": True, "input_dim": 5}, "complete outputs"),
    ],
)
def test_mixture_prior_errors(change, message):
    with pytest.raises(MopError, match=message):
        build_model(mixture_model(**change))


def test_gaps_or_other_orders_are_one_line_errors():
    y, u = data()
    prior = random_prior(2, 2 * 2 + 3, 2)
    gapped = y.clone()
    gapped[0, 5, 1] = float("nan")
    with pytest.raises(MopError, match="needs complete outputs; this record has gaps"):
        mixture_predict(gapped, u, 2, 3, prior)
    with pytest.raises(
        MopError, match=r"holds \(7, 2\) coefficients, ARX\(3, 3\) on 2 outputs needs \(9, 2\)"
    ):
        mixture_predict(y, u, 3, 3, prior)


def test_mixture_prior_needs_its_noise():
    with pytest.raises(MopError, match="rls_prior_noise must be > 0"):
        mixture_model(rls_prior_noise=0.0)


def test_auto_takes_the_mixture_where_it_beats_one_gaussian():
    """dead-time (examples/dead_time.py): a dead time of 1-3 samples puts the input's weight on different
    lags, a multimodal prior; auto's mixture predicts its held-out trajectories more than MIXTURE_GAIN
    better than one Gaussian, and the resolved model reads it. Resolving twice gives the same numbers."""
    import_plugin(EXAMPLES / "dead_time.py")
    system = from_dict(SystemConfig, {"family": "dead-time"})
    config = RunConfig(system=system, model=ModelConfig(features="auto"))
    model = resolve_features(config).model
    assert describe_features(model).endswith(f"family prior of {MIXTURE_SIZE} components")
    assert resolve_features(config).model == model
    family = make_family(system, dtype=F64)
    traj = family.generate(200, 50, generator=generator(99))
    p, q = model.rls_order, model.arx_order
    single = resolve_features(
        RunConfig(system=system, model=ModelConfig(rls_order=p, arx_order=q, rls_prior="family"))
    ).model
    priors = [feature_prior(dict_model(m)) for m in (single, model)]
    errors = [identifier_error(traj.y, traj.u, p, q, 20, prior) for prior in priors]
    assert errors[1] < (1 - MIXTURE_GAIN) * errors[0]


def dict_model(model: ModelConfig) -> ModelConfig:
    """The model config with dead-time's dimensions (what resolve_config fills in)."""
    return dataclasses.replace(model, input_dim=2, output_dim=1)


def test_given_orders_with_the_mixture_prior_equal_what_auto_resolves():
    """model.rls_prior=mixture with the orders auto picks on dead-time gives auto's model keys (one mixture,
    two routes), and needs a family: on recorded data it is a one-line error."""
    import_plugin(EXAMPLES / "dead_time.py")
    system = from_dict(SystemConfig, {"family": "dead-time"})
    resolved = resolve_features(RunConfig(system=system, model=ModelConfig(features="auto"))).model
    keys = dict(rls_order=resolved.rls_order, arx_order=resolved.arx_order, rls_prior="mixture")
    given = resolve_features(RunConfig(system=system, model=ModelConfig(**keys))).model
    mixture_keys = ("rls_prior", "rls_prior_cov", "rls_prior_weights", "rls_prior_noise")
    assert all(getattr(given, k) == getattr(resolved, k) for k in mixture_keys)
    on_data = dataclasses.replace(RunConfig(model=ModelConfig(**keys)), data=DataConfig(path="x.csv"))
    with pytest.raises(MopError, match="rls_prior=mixture is a prior of a system family"):
        resolve_features(on_data)
