"""One Gaussian filtering core shared by the Kalman filter, the EKF and the UKF: each supplies only its
time update. Batched over B systems, a loop over time only; float64.

With m_t, P_t the prior mean / covariance of x_t given y_{<t} (and u_{<t}), for t = 0..T:

    yhat_t = C_t m_t,   S_t = C_t P_t C_t^T + R                (predictive mean and covariance of y_t)
    condition on y_t (Joseph form):  K = P C^T S^{-1},  m <- m + K (y_t - C m),
                                     P <- (I - K C) P (I - K C)^T + K R K^T
    time update (the filter's step):  (m, P) <- step(model, m, P, u_t, t)

Missing outputs (NaN in y): only the measured channels o of y_t are conditioned on, i.e. the rows C_o of C
and the block R_oo of R; a step with nothing measured keeps the prior (filterpy's update(None)). Batched, with
a mask M = diag(observed_t) per system, this is condition_on with
    C~ = M C,  R~ = M R M + (I - M),  y~ = M y      (S~ = blockdiag(S_oo, I), so K~ = [K_o, 0] exactly).
The predictive covariance S_t returned is still that of all of y_t.

Steps: kalman_step (linear f(x, u) = A_t x + B u: m <- A_t m + B u_t, P <- A_t P A_t^T + Q), ekf_step
(linearise f at the posterior mean; `project` clips means as the simulator clips states), ukf_step
(unscented transform).
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor

from mop.systems.base import StateSpace, Trajectories, state_space_of

Projection = Callable[[Tensor], Tensor]
# a time update: (model, m (B, n), P (B, n, n), u (B, k) | None, t, projection | None) -> (m, P)
Step = Callable[
    [StateSpace, Tensor, Tensor, "Tensor | None", int, "Projection | None"], tuple[Tensor, Tensor]
]


def condition_on(
    m: Tensor, P: Tensor, y: Tensor, C: Tensor, R: Tensor, observed: Tensor | None = None
) -> tuple[Tensor, Tensor, Tensor]:
    """Measurement update, Joseph form. m (B, n), P (B, n, n), y (B, m) -> (m, P, S (B, m, m)).

    observed (B, m) bool or None (all measured): condition only on the measured channels of y (the entries of
    y elsewhere, NaN, are never read); S is the predictive covariance of the whole y either way.
    """
    if observed is not None:
        return _condition_on_observed(m, P, y, C, R, observed)
    S = C @ P @ C.mT + R  # (B, m, m)
    L = torch.linalg.cholesky(S)  # (B, m, m)
    K = torch.cholesky_solve(C @ P, L).mT  # (B, n, m) = P C^T S^{-1}
    m = m + (K @ (y - (C @ m[..., None])[..., 0])[..., None])[..., 0]
    I_KC = torch.eye(P.shape[-1], dtype=P.dtype, device=P.device) - K @ C  # (B, n, n)
    P = I_KC @ P @ I_KC.mT + K @ R @ K.mT
    return m, P, S


def _condition_on_observed(
    m: Tensor, P: Tensor, y: Tensor, C: Tensor, R: Tensor, observed: Tensor
) -> tuple[Tensor, Tensor, Tensor]:
    """condition_on for the channels `observed` (B, m) only: C~ = M C, R~ = M R M + (I - M), y~ = M y."""
    M = observed.to(P.dtype)  # (B, m)
    C_o = M[..., None] * C  # (B, m, n): rows of unmeasured channels zeroed
    R_o = M[..., None] * R * M[:, None, :] + torch.diag_embed(1 - M)  # (B, m, m)
    y_o = torch.where(observed, y, torch.zeros_like(y))
    S = C @ P @ C.mT + R  # (B, m, m): the predictive covariance of all of y_t, from the prior
    m, P, _ = condition_on(m, P, y_o, C_o, R_o)
    return m, P, S


def gaussian_filter(
    model: StateSpace,
    step: Step,
    y: Tensor,
    u: Tensor | None = None,
    project: bool = True,
    at_prior: Callable[[int, Tensor, Tensor, Projection | None], None] | None = None,
) -> tuple[Tensor, Tensor]:
    """Predictive means yhat (B, T+1, m) and covariances S (B, T+1, m, m) of y_t given y_{<t}, u_{<t}.

    y (B, T+1, m) with NaN where a channel was not measured, u (B, T+1, k) or None; `project` applies the
    model's state projection (if any) to m_0 and inside `step`. at_prior(t, m_t, P_t, projection) is called
    with each prior before it is conditioned on y_t (gaussian_forecast rolls the k-step forecasts out from
    there).
    """
    proj = model.project if project and model.project is not None else None
    m, P = (model.m0 if proj is None else proj(model.m0)), model.P0
    seen = ~torch.isnan(y)  # (B, T+1, m)
    observed = None if bool(seen.all()) else seen
    means, covs = [], []
    for t in range(y.shape[1]):
        C = model.output_matrix(t)
        if at_prior is not None:
            at_prior(t, m, P, proj)
        means.append((C @ m[..., None])[..., 0])
        m, P, S = condition_on(m, P, y[:, t], C, model.R, None if observed is None else observed[:, t])
        covs.append(S)
        m, P = step(model, m, P, None if u is None else u[:, t], t, proj)
    return torch.stack(means, dim=1), torch.stack(covs, dim=1)


def kalman_step(
    model: StateSpace, m: Tensor, P: Tensor, u: Tensor | None, t: int, proj: Projection | None = None
) -> tuple[Tensor, Tensor]:
    """Linear time update: m <- f(m, u_t) = A_t m + B u_t, P <- A_t P A_t^T + Q (symmetrized), A_t = df/dx.

    The mean goes through the model's f, which for the linear models this filter is for is exactly
    A_t m + B u_t (a family with inputs puts B u in f; with no inputs f(m) = A_t m). No projection."""
    A = model.transition_jacobian(m, u, t)  # (B, n, n)
    P = A @ P @ A.mT + model.Q
    m_next = model.f(m[:, None], None if u is None else u[:, None], t)[:, 0]  # (B, n)
    return m_next, 0.5 * (P + P.mT)


def ekf_step(
    model: StateSpace, m: Tensor, P: Tensor, u: Tensor | None, t: int, proj: Projection | None = None
) -> tuple[Tensor, Tensor]:
    """EKF time update: m <- proj(f(proj(m), u)), P <- F P F^T + Q with F = df/dx at the (unprojected)
    posterior mean. With a projection this is the authors' quadrotor EKF: their state class clips the
    posterior mean before the step and the step's result, and the Jacobian is taken before clipping."""
    F = model.transition_jacobian(m, u, t)  # (B, n, n)
    x = m if proj is None else proj(m)
    m_next = model.f(x[:, None], None if u is None else u[:, None], t)[:, 0]  # (B, n)
    return (m_next if proj is None else proj(m_next)), F @ P @ F.mT + model.Q


JITTER_STEPS = 12  # jitter 1e-15 .. 1e-4 of the mean variance, tried in turn (covariance_factor)


def covariance_factor(P: Tensor) -> Tensor:
    """Lower Cholesky factor L (B, n, n) with L L^T = P (B, n, n), a covariance.

    Where rounding has left a system's P not numerically positive definite (the covariance of a noise-free
    system, whose Q and R are 1e-10 jitter, collapses onto a subspace: the UKF on wiener-hammerstein records),
    its symmetric part is factored with the smallest jitter 10^k 1e-15 mean(diag P) I, k = 0..11, that
    succeeds, as square-root-free UKF codes do; every other system's factor is the plain Cholesky's, bit for
    bit. A P that no jitter rescues raises torch's error, as before."""
    L, info = torch.linalg.cholesky_ex(P)
    bad = info > 0  # (B,)
    if not bool(bad.any()):
        return L
    S = 0.5 * (P[bad] + P[bad].mT)
    scale = S.diagonal(dim1=-2, dim2=-1).mean(-1).clamp_min(torch.finfo(P.dtype).tiny)[:, None, None]
    eye = torch.eye(P.shape[-1], dtype=P.dtype, device=P.device)
    fixed, todo = torch.zeros_like(S), torch.ones(S.shape[0], dtype=torch.bool, device=P.device)
    for k in range(JITTER_STEPS):
        Lk, info_k = torch.linalg.cholesky_ex(S + 10.0 ** (k - 15) * scale * eye)
        done = todo & (info_k == 0)
        fixed[done], todo = Lk[done], todo & ~done
        if not bool(todo.any()):
            break
    if bool(todo.any()):
        torch.linalg.cholesky(S[todo])  # raises torch's own error, naming the matrix that failed
    L = L.clone()
    L[bad] = fixed
    return L


def sigma_points(
    m: Tensor, P: Tensor, alpha: float, beta: float, kappa: float
) -> tuple[Tensor, Tensor, Tensor]:
    """X (B, 2n+1, n), Wm (2n+1,), Wc (2n+1,) for N(m, P) (Julier / Merwe scaling); m (B, n), P (B, n, n).

    lambda = alpha^2 (n + kappa) - n,  L L^T = P,
    X = [m, m + sqrt(n + lambda) L_i, m - sqrt(n + lambda) L_i],
    Wm_0 = lambda / (n + lambda), Wc_0 = Wm_0 + 1 - alpha^2 + beta, Wm_i = Wc_i = 1 / (2 (n + lambda)).
    """
    n = m.shape[-1]
    lam = alpha**2 * (n + kappa) - n
    L = covariance_factor((n + lam) * P)  # (B, n, n)
    X = torch.cat([m[:, None], m[:, None] + L.mT, m[:, None] - L.mT], dim=1)  # rows of L^T = columns of L
    Wm = torch.full((2 * n + 1,), 0.5 / (n + lam), dtype=m.dtype, device=m.device)
    Wm[0] = lam / (n + lam)
    Wc = Wm.clone()
    Wc[0] = Wm[0] + 1 - alpha**2 + beta
    return X, Wm, Wc


def ukf_step_with(alpha: float = 1.0, beta: float = 0.0, kappa: float = 0.0) -> Step:
    """The unscented time update: m <- proj(sum_i Wm_i f(X_i, u)), P <- sum_i Wc_i (f(X_i) - m)(...)^T + Q.

    Only the predicted mean is projected (clipping the posterior too scored worse on the quadrotor)."""

    def step(
        model: StateSpace, m: Tensor, P: Tensor, u: Tensor | None, t: int, proj: Projection | None = None
    ) -> tuple[Tensor, Tensor]:
        X, Wm, Wc = sigma_points(m, P, alpha, beta, kappa)  # (B, 2n+1, n)
        u_rep = None if u is None else u[:, None].expand(-1, X.shape[1], -1)  # (B, 2n+1, k)
        FX = model.f(X, u_rep, t)  # (B, 2n+1, n)
        m = torch.einsum("i,bin->bn", Wm, FX)
        D = FX - m[:, None]  # (B, 2n+1, n)
        P = torch.einsum("i,bin,bik->bnk", Wc, D, D) + model.Q
        return (m if proj is None else proj(m)), 0.5 * (P + P.mT)

    return step


def gaussian_forecast(
    model: StateSpace, step: Step, y: Tensor, u: Tensor | None, steps: int, project: bool = True
) -> tuple[Tensor, Tensor]:
    """k-step forecasts: mean (B, T+1, K, m) and covariance (B, T+1, K, m, m), K = steps.

    From the prior (m_t, P_t) of x_t given y_{<t} the filter's own time update is applied j times with no
    measurement (inputs u_t..u_{t+j-1}, the same projection as the filter):
        mean[:, t, j] = C_{t+j} m_{t+j|t-1},  cov[:, t, j] = C_{t+j} P_{t+j|t-1} C_{t+j}^T + R
    (linear: m_{t+j|t-1} = A^j m_t, P_{t+j|t-1} = A^j P_t A^j^T + sum_{i<j} A^i Q A^i^T). j = 0 is the
    filter's one-step prediction. Entries with t + j > T (no such output) are NaN.
    """
    B, T1, m_out = y.shape
    nan = float("nan")
    mean = y.new_full((B, T1, steps, m_out), nan)
    cov = y.new_full((B, T1, steps, m_out, m_out), nan)

    def roll(t: int, m: Tensor, P: Tensor, proj: Projection | None) -> None:
        last = min(steps, T1 - t)
        for j in range(last):
            C = model.output_matrix(t + j)
            mean[:, t, j] = (C @ m[..., None])[..., 0]
            cov[:, t, j] = C @ P @ C.mT + model.R
            if j + 1 < last:
                m, P = step(model, m, P, None if u is None else u[:, t + j], t + j, proj)

    gaussian_filter(model, step, y, u, project, at_prior=roll)
    return mean, cov


def gaussian_simulate(
    model: StateSpace, step: Step, y: Tensor, u: Tensor | None, context: int, project: bool = True
) -> tuple[Tensor, Tensor]:
    """Free-run simulation after `context` = c outputs: mean (B, T+1-c, m) and covariance (B, T+1-c, m, m)
    of y_{c+j} given y_{<c} and u_{<c+j}: the filter over y_0..y_{c-1}, then its time update alone
    (gaussian_forecast's rollout from the one origin c)."""
    prior: dict[str, object] = {}

    def keep(t: int, m: Tensor, P: Tensor, proj: Projection | None) -> None:
        if t == context:
            prior.update(m=m, P=P, proj=proj)

    gaussian_filter(
        model, step, y[:, : context + 1], None if u is None else u[:, : context + 1], project, keep
    )
    m, P, proj = prior["m"], prior["P"], prior["proj"]
    means, covs = [], []
    for t in range(context, y.shape[1]):
        C = model.output_matrix(t)
        means.append((C @ m[..., None])[..., 0])
        covs.append(C @ P @ C.mT + model.R)
        if t + 1 < y.shape[1]:
            m, P = step(model, m, P, None if u is None else u[:, t], t, proj)
    return torch.stack(means, dim=1), torch.stack(covs, dim=1)


def filter_forecast(
    model: StateSpace, step: Step, traj: Trajectories, steps: int, project: bool = True
) -> tuple[Tensor, Tensor]:
    """(mean, var) each (B, T+1, K, m) in traj.y's dtype: gaussian_forecast's means and diagonal variances."""
    u = None if traj.u is None else traj.u.double()
    mean, cov = gaussian_forecast(model, step, traj.y.double(), u, steps, project)
    return mean.to(traj.y.dtype), torch.diagonal(cov, dim1=-2, dim2=-1).to(traj.y.dtype)


def filter_distribution(
    model: StateSpace, step: Step, traj: Trajectories, project: bool = True
) -> tuple[Tensor, Tensor]:
    """(mean, var) each (B, T+1, m) in traj.y's dtype: C_t m_t and diag(S_t)."""
    u = None if traj.u is None else traj.u.double()
    mean, S = gaussian_filter(model, step, traj.y.double(), u, project)
    return mean.to(traj.y.dtype), torch.diagonal(S, dim1=-2, dim2=-1).to(traj.y.dtype)


class GaussianFilterPredictor:
    """A Gaussian filter that knows each system (the family's StateSpace of traj.params), as a predictor
    with a predictive distribution. step: kalman_step, ekf_step or a ukf_step_with(...) step."""

    def __init__(self, step: Step, project: bool = True, name: str = "") -> None:
        self.step, self.project, self.name = step, project, name

    def predict_distribution(self, traj: Trajectories) -> tuple[Tensor, Tensor]:
        return filter_distribution(state_space_of(traj), self.step, traj, self.project)

    def predict(self, traj: Trajectories) -> Tensor:
        return self.predict_distribution(traj)[0]

    def forecast_distribution(self, traj: Trajectories, steps: int) -> tuple[Tensor, Tensor]:
        """(mean, var) each (B, T+1, K, m): gaussian_forecast of the family's StateSpace."""
        return filter_forecast(state_space_of(traj), self.step, traj, steps, self.project)

    def forecast(self, traj: Trajectories, steps: int) -> Tensor:
        """(B, T+1, K, m): forecast[:, t, j] predicts y_{t+j} from y_{<t} (NaN where t + j > T)."""
        return self.forecast_distribution(traj, steps)[0]

    def simulate(self, traj: Trajectories, context: int) -> Tensor:
        """(B, T+1-c, m): y_{c+j} from y_{<c} and the inputs (gaussian_simulate's mean)."""
        u = None if traj.u is None else traj.u.double()
        model = state_space_of(traj)
        mean, _ = gaussian_simulate(model, self.step, traj.y.double(), u, context, self.project)
        return mean.to(traj.y.dtype)
