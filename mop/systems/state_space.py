"""The state-space description a filter that knows the system consumes (StateSpace), and the linear-Gaussian
model as one (linear_state_space; from arrays given with user data, linear_model_from_params)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor

from mop.errors import MopError
from mop.systems.params import SystemParams

Transition = Callable[
    [Tensor, "Tensor | None", int], Tensor
]  # (x (B, N, n), u (B, N, k) | None, t) -> (B, N, n)
TransitionJacobian = Callable[
    [Tensor, "Tensor | None", int], Tensor
]  # (x (B, n), u (B, k) | None, t) -> (B, n, n)
Projection = Callable[[Tensor], Tensor]  # x (..., n) -> (..., n), e.g. clipping to bounds


@dataclass(frozen=True)
class StateSpace:
    """The model a filter that knows the system is given, batched over B systems (float64):

        x_{t+1} = project(f(x_t, u_t, t) + w_t),  w_t ~ N(0, Q);   y_t = C_t x_t + v_t,  v_t ~ N(0, R);
        x_0 ~ N(m0, P0) (then projected).

    f maps point sets x (B, N, n) (N = 1 for a mean, N particles or sigma points) with u (B, N, k) | None.
    jacobian: df/dx at x (B, n), u (B, k) | None -> (B, n, n); None means autograd (torch.func.jacrev).
    C: (B, m, n), or a function t -> (B, m, n) for time-varying outputs (switching systems).
    project: the simulator's state projection (the quadrotor's clipping); None for none.
    """

    f: Transition
    C: Tensor | Callable[[int], Tensor]
    Q: Tensor
    R: Tensor
    m0: Tensor
    P0: Tensor
    jacobian: TransitionJacobian | None = None
    project: Projection | None = None

    def output_matrix(self, t: int) -> Tensor:
        return self.C(t) if callable(self.C) else self.C

    def transition_jacobian(self, x: Tensor, u: Tensor | None, t: int) -> Tensor:
        """(B, n, n) df/dx at x (B, n): the family's, or autograd through f. Each system's next state depends
        on its own state only, so the Jacobian of sum_b f(x_b) with respect to x_b is system b's."""
        if self.jacobian is not None:
            return self.jacobian(x, u, t)
        u_set = None if u is None else u[:, None]
        summed = torch.func.jacrev(lambda z: self.f(z[:, None], u_set, t)[:, 0].sum(0))(x)  # (n, B, n)
        return summed.permute(1, 0, 2)


def linear_state_space(
    A: Tensor,
    C: Tensor,
    Q: Tensor,
    R: Tensor,
    P0: Tensor,
    B: Tensor | None = None,
    m0: Tensor | None = None,
) -> StateSpace:
    """x_{t+1} = A x_t + B u_t + w_t, y_t = C x_t + v_t, x_0 ~ N(m0, P0) (m0 default 0); float64.

    A (B, n, n), C (B, m, n), Q (B, n, n), R (B, m, m), P0 (B, n, n), B (B, n, k) or None (no inputs: the
    inputs, if any, do not act on the state), m0 (B, n) or None."""
    A, C, Q, R, P0 = (M.double() for M in (A, C, Q, R, P0))
    Bu = None if B is None else B.double()

    def f(x: Tensor, u: Tensor | None, t: int) -> Tensor:
        if Bu is None or u is None:
            return x @ A.mT
        return x @ A.mT + u @ Bu.mT  # (B, N, n)

    return StateSpace(
        f=f,
        C=C,
        Q=Q,
        R=R,
        m0=A.new_zeros(A.shape[:-1]) if m0 is None else m0.double(),
        P0=P0,
        jacobian=lambda x, u, t: A,
    )


@dataclass(frozen=True)
class LinearModelParams(SystemParams):
    """A known linear-Gaussian model given with data that has no family (mop predict kalman DATA.npz):

        x_{t+1} = A x_t + B u_t + w_t, w_t ~ N(0, Q);  y_t = C x_t + v_t, v_t ~ N(0, R);
        x_0 ~ N(x0_mean, P0).

    A (B, n, n), C (B, m, n), Q (B, n, n), R (B, m, m); optional B (B, n, k) (None: the inputs do not act),
    P0 (B, n, n) (None: I), x0_mean (B, n) (None: 0)."""

    A: Tensor
    C: Tensor
    Q: Tensor
    R: Tensor
    B: Tensor | None = None
    P0: Tensor | None = None
    x0_mean: Tensor | None = None


LINEAR_MODEL_ARRAYS = LinearModelParams.required()


def linear_model_from_params(params: LinearModelParams) -> StateSpace:
    """The StateSpace of a known linear-Gaussian model (LinearModelParams; defaults P0 = I, x0_mean = 0).
    MopError naming the first misshapen array (as param_<name>, the .npz key)."""
    p, A = params, params.A
    if A.ndim != 3 or A.shape[1] != A.shape[2]:
        raise MopError(f"param_A has shape {tuple(A.shape)}, need (B, n, n)")
    batch, n, m = A.shape[0], A.shape[-1], p.C.shape[-2]
    k = None if p.B is None else p.B.shape[-1]
    expected = {"C": (batch, m, n), "Q": (batch, n, n), "R": (batch, m, m), "P0": (batch, n, n)}
    expected |= {"x0_mean": (batch, n), "B": (batch, n, k), "A": (batch, n, n)}
    for name, value in p.as_dict().items():
        if value is not None and tuple(value.shape) != expected[name]:
            raise MopError(
                f"param_{name} has shape {tuple(value.shape)}, need {expected[name]} for A {n} x {n}"
            )
    P0 = torch.eye(n, dtype=torch.float64, device=A.device).expand(batch, n, n) if p.P0 is None else p.P0
    x0 = A.new_zeros(batch, n) if p.x0_mean is None else p.x0_mean
    return linear_state_space(A, p.C, p.Q, p.R, P0, p.B, x0)
