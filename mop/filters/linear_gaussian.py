"""Linear-Gaussian systems as matrices, and their Kalman filter in predictor form with the gains computed
ahead (the gains do not depend on the data):

    x_{t+1} = A x_t + B u_t + w_t,  w_t ~ N(0, Q);   y_t = C x_t + v_t,  v_t ~ N(0, R);   x_0 ~ N(m0, P0)

    yhat_t = C m_t,  e_t = y_t - yhat_t,  m_{t+1} = A m_t + B u_t + K_t e_t,  m_0 = m0,
    S_t = C P_t C^T + R,  K_t = A P_t C^T S_t^{-1},  P_{t+1} = A P_t A^T + Q - K_t S_t K_t^T,  P_0 = P0.

The same predictions as mop.filters.kalman's filter (its Joseph-form core, which also takes gaps and any
StateSpace) at a fraction of the cost: a few batched matrix products per step, so it can run on every
training batch (train.target = "optimal") and on a bank of many systems (mop.filters.bayes). Complete
outputs only.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import torch
from torch import Tensor

from mop.errors import MopError
from mop.systems.base import StateSpace, SystemFamily, SystemParams

AFFINE_TOLERANCE = 1e-9
STEADY_TOLERANCE = 1e-13  # max |P_{t+1} - P_t| <= 1e-13 (1 + max |P_t|): P_t is the fixed point, K_t final


@dataclass(frozen=True)
class LinearSystems:
    """M linear-Gaussian systems (the module docstring), float64: A (M, n, n), B (M, n, k) or None (no
    inputs), C (M, m, n), Q (M, n, n), R (M, m, m), m0 (M, n), P0 (M, n, n)."""

    A: Tensor
    B: Tensor | None
    C: Tensor
    Q: Tensor
    R: Tensor
    m0: Tensor
    P0: Tensor

    def __getitem__(self, index: slice) -> LinearSystems:
        """The systems `index` (a slice along M)."""
        parts = {f.name: getattr(self, f.name) for f in fields(self)}
        return LinearSystems(**{k: None if v is None else v[index] for k, v in parts.items()})


def family_systems(family: SystemFamily, params: SystemParams, horizon: int) -> LinearSystems:
    """The systems `params` of `family` as matrices (linear_systems, time invariance checked over
    t = 0..horizon); MopError where the family's state space is not the exact model of its systems."""
    if not family.exact_state_space:
        raise MopError(
            f"the {family.name} family's state space only approximates its systems, so its Kalman filter is "
            "not their optimum; this needs a family whose state space is exact"
        )
    return linear_systems(family.state_space(params), family.input_dim, horizon)


def linear_systems(model: StateSpace, input_dim: int, horizon: int = 0) -> LinearSystems:
    """The StateSpace of M systems as matrices: A = df/dx, B u = f(0, u); MopError where f is not linear in x
    and u (checked at seeded random points), has a constant term, changes over t = 0..horizon, or C varies
    in time."""
    if callable(model.C):
        raise MopError("the family's output matrix varies in time; this filter needs a fixed C")
    M, n = model.m0.shape
    dtype = model.m0.dtype
    zero_x = model.m0.new_zeros(M, 1, n)
    zero_u = None if input_dim == 0 else model.m0.new_zeros(M, 1, input_dim)
    offset = model.f(zero_x, zero_u, 0)[:, 0]  # (M, n)
    A = model.transition_jacobian(zero_x[:, 0], None if zero_u is None else zero_u[:, 0], 0)
    B = None
    if input_dim:
        eye = torch.eye(input_dim, dtype=dtype).expand(M, input_dim, input_dim).contiguous()
        B = (model.f(model.m0.new_zeros(M, input_dim, n), eye, 0) - offset[:, None]).mT  # (M, n, k)
    gen = torch.Generator().manual_seed(0)  # the points the linearity check reads
    x = torch.randn(M, 3, n, dtype=dtype, generator=gen)
    u = None if not input_dim else torch.randn(M, 3, input_dim, dtype=dtype, generator=gen)
    linear = x @ A.mT + (0 if B is None else u @ B.mT)
    scale = 1 + linear.abs().max()
    first = model.f(x, u, 0)
    if (first - offset[:, None] - linear).abs().max() > AFFINE_TOLERANCE * scale:
        raise MopError("the family's dynamics are not linear; this filter needs a linear-Gaussian family")
    if offset.abs().max() > AFFINE_TOLERANCE * scale:
        raise MopError("the family's dynamics have a constant term; this filter takes x -> A x + B u only")
    if any((model.f(x, u, t) - first).abs().max() > AFFINE_TOLERANCE * scale for t in range(1, horizon + 1)):
        raise MopError("the family's dynamics change in time; this filter needs time-invariant systems")
    return LinearSystems(
        A.double(),
        None if B is None else B.double(),
        model.C.double(),
        model.Q.double(),
        model.R.double(),
        model.m0.double(),
        model.P0.double(),
    )


def predictor_gains(
    systems: LinearSystems, horizon: int, likelihood: bool = True
) -> tuple[Tensor, Tensor | None, Tensor | None]:
    """For t = 0..horizon: the predictor gains K_t (M, T+1, n, m) (the module docstring's recursion) and,
    with likelihood, S_t^{-1} (M, T+1, m, m) and log det S_t (M, T+1) (else None, None). Once P_t stops
    changing (STEADY_TOLERANCE, all M systems) the later steps repeat the last gain."""
    A, C, Q, R, P = systems.A, systems.C, systems.Q, systems.R, systems.P0
    gains, inverses, logdets = [], [], []
    for _ in range(horizon + 1):
        S = C @ P @ C.mT + R
        L = torch.linalg.cholesky(S)
        APC = A @ P @ C.mT  # (M, n, m)
        K = torch.cholesky_solve(APC.mT, L).mT  # (M, n, m) = A P C^T S^{-1}
        gains.append(K)
        if likelihood:
            inverses.append(torch.cholesky_inverse(L))
            logdets.append(2 * L.diagonal(dim1=-2, dim2=-1).log().sum(-1))
        P_next = A @ P @ A.mT + Q - K @ APC.mT
        P_next = 0.5 * (P_next + P_next.mT)
        if (P_next - P).abs().max() <= STEADY_TOLERANCE * (1 + P.abs().max()):  # at the Riccati fixed point
            break
        P = P_next
    repeat = horizon + 1 - len(gains)  # steps left after the fixed point: the same K, S as the last step
    gains += gains[-1:] * repeat
    inverses += inverses[-1:] * repeat
    logdets += logdets[-1:] * repeat
    if not likelihood:
        return torch.stack(gains, 1), None, None
    return torch.stack(gains, 1), torch.stack(inverses, 1), torch.stack(logdets, 1)


def filter_means(systems: LinearSystems, y: Tensor, u: Tensor | None, gains: Tensor) -> tuple[Tensor, Tensor]:
    """(prior means x (M, N, T+1, n) of x_t given y_{<t}, innovations e = y_t - C x_t (M, N, T+1, m)) of the
    M systems' filters with predictor gains (M, T+1, n, m) (predictor_gains) on trajectories y (M|1, N, T+1,
    m), u (M|1, N, T+1, k) or None: a leading 1 runs every system on the same N trajectories, M runs each
    system on its own."""
    mean = systems.m0[:, None].expand(-1, y.shape[1], -1)  # (M, N, n)
    means, errors = [], []
    for t in range(y.shape[2]):
        e = y[:, :, t] - mean @ systems.C.mT  # (M, N, m)
        means.append(mean)
        errors.append(e)
        mean = mean @ systems.A.mT + e @ gains[:, t].mT
        if systems.B is not None and u is not None:
            mean = mean + u[:, :, t] @ systems.B.mT
    return torch.stack(means, 2), torch.stack(errors, 2)


def kalman_means(systems: LinearSystems, y: Tensor, u: Tensor | None) -> Tensor:
    """yhat (M, T+1, m): yhat[:, t] = E[y_t | y_{<t}, u_{<t}] by each system's own Kalman filter on its own
    trajectory y (M, T+1, m) (complete), u (M, T+1, k) or None."""
    if torch.isnan(y).any():
        raise MopError("kalman_means: the outputs have gaps (NaN); use mop.filters.kalman, which skips them")
    y = y.double()
    K = predictor_gains(systems, y.shape[1] - 1, likelihood=False)[0]
    x, _ = filter_means(systems, y[:, None], None if u is None else u.double()[:, None], K)
    return (x @ systems.C[:, None].mT)[:, 0]
