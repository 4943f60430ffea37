"""Bootstrap particle filter one-step predictions, batched over systems and particles (a loop over time only).

With N particles X_t^i ~ p(x_t | y_{<t}) (start: X_0^i ~ N(m_0, P_0)):

    yhat_t = C mean_i(X_t^i)
    weights  w_i ∝ N(y_t; C X_t^i, R),  systematic resampling by w
    propagate X_{t+1}^i = project(f(X_t^i, u_t) + L eps_i),  L L^T = Q,  eps_i ~ N(0, I)

The filter knows (f, C, Q, R) from traj.params and, with project=True ("pf"), the family's state projection
(the quadrotor's clipping, applied to the initial and propagated particles, exactly as the simulator clips the
state); project=False gives "pf-noclip".
"""

from __future__ import annotations

import torch
from torch import Tensor

from mop.filters.ekf import Dynamics, Projection, identity, system_model
from mop.systems.base import Trajectories


def _condition_on(X: Tensor, y: Tensor, C: Tensor, R_inv: Tensor, generator: torch.Generator) -> Tensor:
    """Resample particles X (B, N, n) by their likelihood N(y; C x, R) of y (B, m) (systematic resampling)."""
    resid = y[:, None] - X @ C.mT  # (B, N, m)
    log_w = -0.5 * ((resid @ R_inv) * resid).sum(-1)  # (B, N)
    w = torch.softmax(log_w, dim=-1)
    B, N = w.shape
    cdf = w.cumsum(-1)
    cdf[:, -1] = 1.0
    offset = torch.rand((B, 1), generator=generator, device=generator.device, dtype=w.dtype)
    positions = (offset + torch.arange(N, dtype=w.dtype, device=w.device)) / N  # (B, N)
    idx = torch.searchsorted(cdf, positions).clamp_max(N - 1)
    return torch.gather(X, 1, idx[..., None].expand_as(X))


def _predict(X: Tensor, u: Tensor | None, f: Dynamics, L_Q: Tensor, generator: torch.Generator) -> Tensor:
    """X (B, N, n) -> f(X, u) + w, w ~ N(0, Q) per particle."""
    u_rep = None if u is None else u[:, None].expand(-1, X.shape[1], -1)  # (B, N, k)
    FX = f(X, u_rep)  # (B, N, n)
    eps = torch.randn(X.shape, generator=generator, device=generator.device, dtype=X.dtype)
    return FX + eps @ L_Q.mT


def particle_filter_predict(
    f: Dynamics,
    C: Tensor,
    Q: Tensor,
    R: Tensor,
    m0: Tensor,
    P0: Tensor,
    y: Tensor,
    u: Tensor | None = None,
    *,
    num_particles: int = 1000,
    generator: torch.Generator,
    project: Projection | None = None,
) -> Tensor:
    """One-step predictions yhat (B, T+1, m), shapes and `project` (here applied to every particle) as in
    mop.filters.ekf.extended_kalman_predict."""
    project = project or identity
    B, n = m0.shape
    L_Q = torch.linalg.cholesky(Q + 1e-12 * torch.eye(n, dtype=Q.dtype, device=Q.device))
    L_0 = torch.linalg.cholesky(P0 + 1e-12 * torch.eye(n, dtype=Q.dtype, device=Q.device))
    eps = torch.randn((B, num_particles, n), generator=generator, device=generator.device, dtype=m0.dtype)
    X = project(m0[:, None] + eps @ L_0.mT)  # (B, N, n)
    R_inv = torch.linalg.inv(R)  # (B, m, m)
    preds = []
    for t in range(y.shape[1]):
        preds.append((C @ X.mean(1)[..., None])[..., 0])  # (B, m)
        X = _condition_on(X, y[:, t], C, R_inv, generator)
        X = project(_predict(X, None if u is None else u[:, t], f, L_Q, generator))
    return torch.stack(preds, dim=1)


def pf_predict(
    params: dict[str, Tensor],
    y: Tensor,
    u: Tensor | None = None,
    *,
    num_particles: int = 1000,
    seed: int = 0,
    project: bool = True,
) -> Tensor:
    """Particle-filter predictions (B, T+1, m) for systems in `params` (quadrotor or linear), in float64."""
    model = system_model(params)
    p = {k: params[k].double() for k in ("C", "Q", "R", "P0")}
    generator = torch.Generator(device=y.device).manual_seed(seed)
    u = None if u is None else u.double()
    return particle_filter_predict(
        model.f,
        p["C"],
        p["Q"],
        p["R"],
        model.m0,
        p["P0"],
        y.double(),
        u,
        num_particles=num_particles,
        generator=generator,
        project=model.project if project else None,
    )


class ParticleFilterPredictor:
    """Bootstrap particle filter knowing each system's parameters; seeded, `num_particles` per system."""

    def __init__(self, num_particles: int = 1000, seed: int = 0, project: bool = True) -> None:
        self.num_particles, self.seed, self.project = num_particles, seed, project
        self.name = "pf" if project else "pf-noclip"  # pf also knows the quadrotor's state clipping

    def predict(self, traj: Trajectories) -> Tensor:
        yhat = pf_predict(
            traj.params,
            traj.y,
            traj.u,
            num_particles=self.num_particles,
            seed=self.seed,
            project=self.project,
        )
        return yhat.to(traj.y.dtype)
