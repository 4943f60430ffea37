"""ARX under a mixture-of-Gaussians prior on its coefficients: K recursive least squares, weighed by evidence.

The family's empirical-Bayes prior of mop.train.auto is one Gaussian, N(theta_0, sigma^2 P_0). A family's
coefficients are often not one blob: a dead time of 1, 2 or 3 samples puts the input's weight on different
lags, and log-uniform springs or heat capacities spread them along curves. With the prior

    theta ~ sum_k w_k N(mu_k, sigma^2 P_k),    y_{s} = theta^T phi_{s-1} + e_s,   e_s ~ N(0, sigma^2 I_m),

the posterior is again a mixture: component k's posterior is the RLS recursion started from (mu_k, P_k)
(mop.filters.rls.rls_innovation_update: its theta is that component's posterior mean), and its weight is
w_k times the evidence of the pairs so far, the product of the one-step predictive densities

    y_s | past, k ~ N(theta_k^T phi_{s-1}, sigma^2 (1 + phi_{s-1}^T P_k phi_{s-1}) I_m),

so the posterior-mean prediction is yhat_{t+1} = sum_k w_k(t) theta_k(t)^T phi_t. One component (K = 1) is
the single-prior recursion (arx_predict with prior (mu_1, P_1)), to rounding. sigma^2 is the family's residual
variance (fixed): an online estimate per system (Student-t weights) changed the identifier's error by less
than 0.1% on two-mass and dead-time, whose per-system residual variances span a factor of 9.

Start-up and regressors as mop.filters.arx (r = max(p, q); yhat_0 = 0, yhat_t = y_{t-1} for 1 <= t <= r).
Outputs with gaps are not handled here (a model with this feature has no observation mask).

fit_mixture fits (w, mu, P) by expectation-maximisation to per-system least-squares coefficients theta_i
(d, m) of many simulated systems, each output's column a draw from the system's component, the covariance of
a component shared by the m columns (as P is in the recursion).
"""

from __future__ import annotations

import dataclasses
import math

import torch
from torch import Tensor

from mop.errors import MopError
from mop.filters.arx import arx_regressors
from mop.filters.rls import rls_innovation_update

EM_ITERATIONS = 200
EM_TOLERANCE = 1e-6  # ... or until the mean log-likelihood per system gains less than this
EM_SEED = 0  # the components' initial means: K systems drawn with this seed
COV_FLOOR = 1e-3  # each component's covariance + 1e-3 mean(diag of the pooled covariance) I


@dataclasses.dataclass(frozen=True)
class MixturePrior:
    """weights (K,) summing to 1; means (K, d, m); covs (K, d, d), each component's P_0 (its coefficient
    covariance over the noise variance); noise: sigma^2, the residual variance in the outputs' units."""

    weights: Tensor
    means: Tensor
    covs: Tensor
    noise: float

    @property
    def size(self) -> int:
        return int(self.weights.shape[0])


class MixtureState:
    """The K recursions of B systems, flat over (system, component): theta (B K, d, m), P (B K, d, d), and
    the log weights (B, K); float64."""

    def __init__(self, prior: MixturePrior, batch_size: int, like: Tensor) -> None:
        f64 = dict(dtype=torch.float64, device=like.device)
        K, d, m = prior.means.shape
        self.K, self.noise = K, prior.noise
        self.theta = prior.means.to(**f64).repeat(batch_size, 1, 1)  # row b K + k: system b, component k
        self.P = prior.covs.to(**f64).repeat(batch_size, 1, 1)
        self.log_w = prior.weights.to(**f64).log().repeat(batch_size, 1)  # (B, K)

    def update(self, phi: Tensor, y: Tensor, repeated: bool = False) -> None:
        """Weigh each component by the density of y_s (B, m) given phi_{s-1} (B, d), then fit the pair
        (repeated: phi and y given once per component already, (B K, d) and (B K, m), float64)."""
        K = self.K
        if not repeated:
            phi, y = phi.double().repeat_interleave(K, 0), y.double().repeat_interleave(K, 0)
        self.theta, self.P, err, s = rls_innovation_update(self.theta, self.P, phi, y)
        log_density = err.pow(2).sum(-1) / (self.noise * s) + y.shape[-1] * s.log()  # (B K,), up to -0.5
        self.log_w = self.log_w - 0.5 * log_density.reshape(-1, K)
        self.log_w = self.log_w - self.log_w.max(-1, keepdim=True).values  # keep them near 0

    def predict(self, phi: Tensor, repeated: bool = False) -> Tensor:
        """(B, m): the posterior-mean prediction theta^T phi (phi (B, d), or (B K, d) with repeated) under
        the mixture."""
        B, K = self.log_w.shape
        phi = phi if repeated else phi.double().repeat_interleave(K, 0)
        each = torch.einsum("nim,ni->nm", self.theta, phi)  # (B K, m)
        w = torch.softmax(self.log_w, -1)  # (B, K)
        return (w[..., None] * each.reshape(B, K, -1)).sum(1)


def mixture_predict(y: Tensor, u: Tensor | None, p: int, q: int, prior: MixturePrior) -> Tensor:
    """One-step predictions yhat (B, T, m), yhat[:, t] of y_t from y_{<t} and u_{<t}, for y (B, T, m)
    complete and u (B, T, k) or None (q ignored): ARX(p, q) (RLS-AR(p) without inputs) under the mixture
    prior, float64, by its K recursions one pair at a time (MixtureState, as the streaming feature runs
    them); start-up as mop.filters.arx.arx_predict. Outputs with gaps, or a prior of other orders, are a
    one-line MopError."""
    if torch.isnan(y).any():
        raise MopError("the ARX feature under a mixture prior needs complete outputs; this record has gaps")
    B, T, m = y.shape
    r = p if u is None else max(p, q)
    phi = arx_regressors(y.double(), None if u is None else u.double(), p, max(q, 1))
    if phi.shape[-1] != prior.means.shape[1] or m != prior.means.shape[2]:
        raise MopError(
            f"the mixture prior holds {tuple(prior.means.shape[1:])} coefficients, ARX({p}, {q}) on {m} "
            f"outputs needs {(phi.shape[-1], m)}"
        )
    state = MixtureState(prior, B, y)
    phi_k, y_k = phi.repeat_interleave(prior.size, 0), y.double().repeat_interleave(prior.size, 0)
    preds = [y.new_zeros(B, m).double()] + [y[:, t - 1].double() for t in range(1, min(r + 1, T))]
    for t in range(r + 1, T):
        state.update(phi_k[:, t - 2], y_k[:, t - 1], repeated=True)  # the newest pair (phi_{t-2}, y_{t-1})
        preds.append(state.predict(phi_k[:, t - 1], repeated=True))
    return torch.stack(preds, dim=1)


def fit_mixture(theta: Tensor, noise: float, size: int, ridge: float = 1e-6) -> MixturePrior:
    """EM fit of a size-K mixture to per-system coefficients theta (N, d, m) (each system's m columns drawn
    from one component, a covariance shared by them); covs returned over `noise` (sigma^2), floored by
    COV_FLOOR and ridge times the mean variance (positive definite where a coefficient never varies).
    Deterministic: the initial means are K systems drawn with EM_SEED, all covariances start pooled; it
    stops after EM_ITERATIONS or once the mean log-likelihood per system gains less than EM_TOLERANCE."""
    theta = theta.double()
    N, d, m = theta.shape
    if size < 1 or size > N:
        raise MopError(f"a mixture of {size} components needs 1 <= K <= {N} (the systems fitted)")
    dev = theta - theta.mean(0)
    pooled = torch.einsum("nim,njm->ij", dev, dev) / (N * m)
    floor = (COV_FLOOR + ridge) * pooled.diagonal().mean().clamp_min(1e-300) * torch.eye(d, dtype=theta.dtype)
    g = torch.Generator().manual_seed(EM_SEED)
    means = theta[torch.randperm(N, generator=g)[:size]].clone()  # (K, d, m)
    covs = (pooled + floor).expand(size, d, d).clone()
    weights = torch.full((size,), 1.0 / size, dtype=theta.dtype)
    last = -math.inf
    for _ in range(EM_ITERATIONS if size > 1 else 1):
        log_density = _log_density(theta, weights, means, covs)  # (N, K)
        total = float(torch.logsumexp(log_density, dim=1).mean())
        if total - last < EM_TOLERANCE:
            break
        last = total
        resp = torch.softmax(log_density, dim=1)
        counts = resp.sum(0).clamp_min(1e-12)
        weights = counts / N
        means = torch.einsum("nk,nim->kim", resp, theta) / counts[:, None, None]
        diff = theta[:, None] - means[None]  # (N, K, d, m)
        covs = torch.einsum("nk,nkim,nkjm->kij", resp, diff, diff) / (counts[:, None, None] * m) + floor
    covs = 0.5 * (covs + covs.mT)
    return MixturePrior(weights, means, covs / noise, float(noise))


def _log_density(theta: Tensor, weights: Tensor, means: Tensor, covs: Tensor) -> Tensor:
    """(N, K): log w_k + sum over the m columns of log N(theta_i[:, j]; mu_k[:, j], C_k)."""
    N, d, m = theta.shape
    L = torch.linalg.cholesky(covs)  # (K, d, d)
    precision = torch.cholesky_inverse(L)
    diff = theta[:, None] - means[None]  # (N, K, d, m)
    quad = torch.einsum("nkim,kij,nkjm->nk", diff, precision, diff)
    half_logdet = L.diagonal(dim1=-2, dim2=-1).log().sum(-1)  # (K,)
    return weights.log() - 0.5 * quad - m * half_logdet - 0.5 * m * d * math.log(2 * math.pi)
