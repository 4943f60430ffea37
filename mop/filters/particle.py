"""Bootstrap particle filter one-step predictions, batched over systems and particles (a loop over time only).

With N particles X_t^i ~ p(x_t | y_{<t}) (start: X_0^i ~ N(m_0, P_0)):

    yhat_t = C mean_i(X_t^i)
    weights  w_i ∝ N(y_t; C X_t^i, R),  systematic resampling by w
             (missing outputs, NaN in y: N(y_o; C_o X, R_oo) over the measured channels o; no resampling
             when nothing was measured)
    propagate X_{t+1}^i = project(f(X_t^i, u_t) + L eps_i),  L L^T = Q,  eps_i ~ N(0, I)

The filter knows (f, C, Q, R) from traj.params and, with project=True ("pf"), the family's state projection
(the quadrotor's clipping, applied to the initial and propagated particles, exactly as the simulator clips the
state); project=False gives "pf-noclip".
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor

from mop.predictors import PREDICTORS, nan_beyond_horizon
from mop.systems.base import StateSpace, Trajectories, state_space_of

Dynamics = Callable[[Tensor, "Tensor | None"], Tensor]  # f: (x (B, N, n), u (B, N, k) | None) -> (B, N, n)


def _condition_on(
    X: Tensor,
    y: Tensor,
    C: Tensor,
    R_inv: Tensor,
    generator: torch.Generator,
    observed: Tensor | None = None,
    R: Tensor | None = None,
) -> Tensor:
    """Resample particles X (B, N, n) by their likelihood N(y; C x, R) of y (B, m) (systematic resampling).

    observed (B, m) bool (None: all measured): the likelihood of the measured channels o only,
    N(y_o; C_o x, R_oo), from R~ = M R M + (I - M) with the residual zeroed elsewhere (R (B, m, m) needed);
    systems with nothing measured keep their particles (the draw for the offset is still taken, so the
    generator stays in step).
    """
    if observed is not None:
        M = observed.to(X.dtype)  # (B, m)
        R_inv = torch.linalg.inv(M[..., None] * R * M[:, None, :] + torch.diag_embed(1 - M))
        y = torch.where(observed, y, torch.zeros_like(y))  # its residual is zeroed below
    resid = y[:, None] - X @ C.mT  # (B, N, m)
    if observed is not None:
        resid = resid * M[:, None, :]
    log_w = -0.5 * ((resid @ R_inv) * resid).sum(-1)  # (B, N)
    w = torch.softmax(log_w, dim=-1)
    B, N = w.shape
    cdf = w.cumsum(-1)
    cdf[:, -1] = 1.0
    offset = torch.rand((B, 1), generator=generator, device=generator.device, dtype=w.dtype)
    positions = (offset + torch.arange(N, dtype=w.dtype, device=w.device)) / N  # (B, N)
    idx = torch.searchsorted(cdf, positions).clamp_max(N - 1)
    resampled = torch.gather(X, 1, idx[..., None].expand_as(X))
    if observed is None:
        return resampled
    return torch.where(observed.any(-1)[:, None, None], resampled, X)


def _predict(X: Tensor, u: Tensor | None, f: Dynamics, L_Q: Tensor, generator: torch.Generator) -> Tensor:
    """X (B, N, n) -> f(X, u) + w, w ~ N(0, Q) per particle."""
    u_rep = None if u is None else u[:, None].expand(-1, X.shape[1], -1)  # (B, N, k)
    FX = f(X, u_rep)  # (B, N, n)
    eps = torch.randn(X.shape, generator=generator, device=generator.device, dtype=X.dtype)
    return FX + eps @ L_Q.mT


def rollout_seed(seed: int, origin: int) -> int:
    """The seed of the roll-out draws from forecast origin t: one generator per origin, so a forecast from t
    is the same whichever other origins are forecast (and the filter's own draws never depend on them)."""
    return 1_000_003 * (seed + 1) + origin


def pf_predict(
    model: StateSpace,
    y: Tensor,
    u: Tensor | None = None,
    *,
    num_particles: int = 1000,
    seed: int = 0,
    project: bool = True,
) -> Tensor:
    """One-step predictions yhat (B, T+1, m) for the systems of `model` (a family's StateSpace), float64.

    y (B, T+1, m), u (B, T+1, k) or None; `project` applies the model's projection to every particle.
    """
    return pf_forecast(model, y, u, 1, num_particles=num_particles, seed=seed, project=project)[0][:, :, 0]


def pf_forecast(
    model: StateSpace,
    y: Tensor,
    u: Tensor | None,
    steps: int,
    *,
    num_particles: int = 1000,
    seed: int = 0,
    project: bool = True,
    start: int = 0,
) -> tuple[Tensor, Tensor]:
    """(k-step forecasts (B, T+1, K, m), one-step predictive variances (B, T+1, m)), float64.

    Forecasts: the prior particles of x_t (given y_{<t}) propagated j times
    through f with process-noise draws (and the projection), no resampling; forecast[:, t, j] = C_{t+j}
    mean_i X^i. The roll-out from origin t draws from its own generator (rollout_seed), so j = 0 is
    pf_predict exactly, the filter's own draws do not depend on `steps`, and origins t < start (left NaN for
    j >= 1, not rolled out) change nothing else. Entries with t + j > T are NaN. Variances: the
    diagonal of C Cov_i(X^i) C^T + R over the prior particles of x_t.
    """
    generator = torch.Generator(device=y.device).manual_seed(seed)
    proj = model.project if project and model.project is not None else (lambda x: x)
    y, u = y.double(), None if u is None else u.double()
    L_Q, X = _start(model, y, num_particles, generator, proj)
    R_inv = torch.linalg.inv(model.R)  # (B, m, m)
    B, T1, m = y.shape[0], y.shape[1], model.R.shape[-1]
    seen = ~torch.isnan(y)  # (B, T+1, m)
    observed = None if bool(seen.all()) else seen
    out = y.new_full((B, T1, steps, m), float("nan"))
    var = y.new_empty(B, T1, m)
    roll = Rollout(model, u, L_Q, proj, torch.Generator(device=y.device), seed)
    for t in range(T1):
        C = model.output_matrix(t)
        out[:, t, 0] = (C @ X.mean(1)[..., None])[..., 0]  # (B, m)
        var[:, t] = (X @ C.mT).var(1, unbiased=False) + model.R.diagonal(dim1=-2, dim2=-1)
        roll.ahead(X, t, min(steps, T1 - t) if t >= start else 1, out)
        if observed is None:
            X = _condition_on(X, y[:, t], C, R_inv, generator)
        else:
            X = _condition_on(X, y[:, t], C, R_inv, generator, observed[:, t], model.R)
        f = lambda x, v, t=t: model.f(x, v, t)  # noqa: E731
        X = proj(_predict(X, None if u is None else u[:, t], f, L_Q, generator))
    return nan_beyond_horizon(out), var


def _start(
    model: StateSpace, y: Tensor, num_particles: int, generator: torch.Generator, proj: Callable
) -> tuple[Tensor, Tensor]:
    """(L_Q (B, n, n) with L_Q L_Q^T = Q, the initial particles X_0 (B, N, n) ~ N(m_0, P_0), projected)."""
    B, n = model.m0.shape
    eye = 1e-12 * torch.eye(n, dtype=y.dtype, device=y.device)
    L_Q, L_0 = torch.linalg.cholesky(model.Q + eye), torch.linalg.cholesky(model.P0 + eye)
    eps = torch.randn((B, num_particles, n), generator=generator, device=generator.device, dtype=y.dtype)
    return L_Q, proj(model.m0[:, None] + eps @ L_0.mT)  # (B, N, n)


class Rollout:
    """The k-step roll-outs of pf_forecast: from origin t, the prior particles propagated without
    measurements, with draws from a generator seeded by rollout_seed(seed, t)."""

    def __init__(
        self,
        model: StateSpace,
        u: Tensor | None,
        L_Q: Tensor,
        proj: Callable,
        generator: torch.Generator,
        seed: int,
    ) -> None:
        self.model, self.u, self.L_Q, self.proj, self.generator, self.seed = (
            model,
            u,
            L_Q,
            proj,
            generator,
            seed,
        )

    def ahead(self, X: Tensor, t: int, steps: int, out: Tensor) -> None:
        """out[:, t, j] = C_{t+j} mean_i X_{t+j}^i (j = 1..steps-1) from X (B, N, n), the priors at t."""
        self.generator.manual_seed(rollout_seed(self.seed, t))
        for j in range(1, steps):
            f = lambda x, v, s=t + j - 1: self.model.f(x, v, s)  # noqa: E731
            v = None if self.u is None else self.u[:, t + j - 1]
            X = self.proj(_predict(X, v, f, self.L_Q, self.generator))
            out[:, t, j] = (self.model.output_matrix(t + j) @ X.mean(1)[..., None])[..., 0]


@PREDICTORS.register("pf", needs_system=True, gaussian=True)
class ParticleFilterPredictor:
    """Bootstrap particle filter knowing each system; seeded, `num_particles` per system. project=True
    ("pf") also knows the simulator's state projection (the quadrotor's clipping), False ("pf-noclip") not."""

    name = "pf"

    def __init__(self, num_particles: int = 1000, seed: int = 0, project: bool = True) -> None:
        self.num_particles, self.seed, self.project = num_particles, seed, project
        self.name = "pf" if project else "pf-noclip"

    def predict(self, traj: Trajectories) -> Tensor:
        return self.predict_distribution(traj)[0]

    def predict_distribution(self, traj: Trajectories) -> tuple[Tensor, Tensor]:
        """(mean, var) each (B, T+1, m): the particle mean of C x_t and the particles' spread plus R (the
        moment-matched Gaussian of the particle predictive)."""
        out, var = pf_forecast(
            state_space_of(traj),
            traj.y,
            traj.u,
            1,
            num_particles=self.num_particles,
            seed=self.seed,
            project=self.project,
        )
        return out[:, :, 0].to(traj.y.dtype), var.to(traj.y.dtype)

    def forecast(self, traj: Trajectories, steps: int, start: int = 0) -> Tensor:
        """(B, T+1, K, m): particles propagated through f with seeded noise draws, averaged (pf_forecast);
        origins t < start are not rolled out (NaN for k >= 2)."""
        out, _ = pf_forecast(
            state_space_of(traj),
            traj.y,
            traj.u,
            steps,
            num_particles=self.num_particles,
            seed=self.seed,
            project=self.project,
            start=start,
        )
        return out.to(traj.y.dtype)

    def simulate(self, traj: Trajectories, context: int) -> Tensor:
        """(B, T+1-c, m): the roll-out from origin c = context, forecast[:, c] (the same numbers); origins
        before c are not rolled out: about 1 + 2c / (T+1-c) times fewer propagations than from every one."""
        return self.forecast(traj, traj.horizon + 1 - context, start=context)[:, context]


PREDICTORS.add(
    "pf-noclip", lambda seed=0: ParticleFilterPredictor(seed=seed, project=False), needs_system=True
)
