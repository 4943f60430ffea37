"""The planar quadrotor of the paper's Sec. 5.3 (after Singh et al. 2019), Euler-discretized:

    x_{t+1}   = x + (vx cos(phi) - vz sin(phi)) tau        state (x, z, phi, vx, vz, phidot)
    z_{t+1}   = z + (vx sin(phi) + vz cos(phi)) tau
    phi_{t+1} = phi + phidot tau
    vx_{t+1}  = vx + (vz phidot - g sin(phi)) tau
    vz_{t+1}  = vz + (-vx phidot - g cos(phi) + (u0 + u1) / m) tau
    phidot_{t+1} = phidot + (u0 - u1) l tau / J
    then + w_t, and the state is clipped to BOUNDS;         y_t = C x_t + v_t.

(m, l, J) ~ U[0.5, 2], u0, u1 ~ U[-0.5, 0.5] each step, C (3 x 6) U[0,1], w, v ~ N(0, sigma^2 I), sigma 0.1.
x_0 ~ N(0, x0_std^2 I) per coordinate (x0_std = 1 by default), then clipped.

Where this follows the authors' released code rather than the paper's text (DESIGN.md):
- the angular rate ACCUMULATES (phidot_{t+1} = phidot_t + ...), the physical Euler step; the paper prints
  phidot_{t+1} = (u0 - u1) l tau / J without phidot_t;
- the state is clipped to BOUNDS after each step (noise included) and at t = 0; the paper does not mention it;
- x_0 has unit scale (the paper does not give x_0).
Where we follow the paper's text and deliberately differ from that code (effects measured by
scripts/quadrotor_quirks.py):
- x_0 is drawn independently per coordinate (their code copies ONE N(0, 1) draw into all six coordinates;
  copying it would move mop's EKF error over t in [20, 50) by -0.01);
- the three outputs get independent observation noise (their code shares one draw among them: -0.01).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from mop.errors import check
from mop.systems.base import (
    StateSpace,
    SystemConfig,
    SystemFamily,
    SystemParams,
    Trajectories,
    normal,
    register_family,
    scaled_eye,
    uniform,
)

TAU = 0.1
GRAVITY = 10.0
STATE_DIM, OUTPUT_DIM, INPUT_DIM = 6, 3, 2
# per-coordinate clip bounds of (x, z, phi, vx, vz, phidot), from the authors' code (DESIGN.md)
BOUNDS = (20.0, 20.0, math.pi / 3, 2.0, 2.0, math.pi / 4)
PARAM_RANGE = (0.5, 2.0)
ACTION_RANGE = (-0.5, 0.5)


def dynamics(x: Tensor, u: Tensor, mass: Tensor, length: Tensor, inertia: Tensor) -> Tensor:
    """x_next = f(x, u): (..., 6), (..., 2), params broadcastable to (...,). No noise, no clipping."""
    px, pz, phi, vx, vz, phidot = x.unbind(-1)
    u0, u1 = u.unbind(-1)
    c, s = torch.cos(phi), torch.sin(phi)
    return torch.stack(
        [
            px + (vx * c - vz * s) * TAU,
            pz + (vx * s + vz * c) * TAU,
            phi + phidot * TAU,
            vx + (vz * phidot - GRAVITY * s) * TAU,
            vz + (-vx * phidot - GRAVITY * c + (u0 + u1) / mass) * TAU,
            phidot + (u0 - u1) * length * TAU / inertia,
        ],
        dim=-1,
    )


def dynamics_jacobian(x: Tensor, u: Tensor, mass: Tensor, length: Tensor, inertia: Tensor) -> Tensor:
    """F = df/dx at (x, u): (..., 6, 6). (f does not depend on x through m, l, J or u.)"""
    _, _, phi, vx, vz, phidot = x.unbind(-1)
    c, s = torch.cos(phi), torch.sin(phi)
    one, zero = torch.ones_like(phi), torch.zeros_like(phi)
    rows = [
        [one, zero, (-vx * s - vz * c) * TAU, c * TAU, -s * TAU, zero],
        [zero, one, (vx * c - vz * s) * TAU, s * TAU, c * TAU, zero],
        [zero, zero, one, zero, zero, one * TAU],
        [zero, zero, -GRAVITY * c * TAU, one, phidot * TAU, vz * TAU],
        [zero, zero, GRAVITY * s * TAU, -phidot * TAU, one, -vx * TAU],
        [zero, zero, zero, zero, zero, one],
    ]
    return torch.stack([torch.stack(r, dim=-1) for r in rows], dim=-2)


def clip_state(x: Tensor) -> Tensor:
    """Clip each coordinate of x (..., 6) to [-BOUNDS_i, BOUNDS_i]."""
    bound = torch.tensor(BOUNDS, dtype=x.dtype, device=x.device)
    return torch.maximum(torch.minimum(x, bound), -bound)


@dataclass(frozen=True)
class QuadrotorConfig(SystemConfig):
    """noise_var_w / noise_var_v: variances of w_t, v_t (the paper's 0.01); x0_std: x_0 ~ N(0, x0_std^2 I)."""

    family: str = "quadrotor"
    noise_var_w: float = 0.01
    noise_var_v: float = 0.01
    x0_std: float = 1.0

    def __post_init__(self) -> None:
        super().__post_init__()
        check(
            self.noise_var_w >= 0 and self.noise_var_v >= 0,
            f"noise variances must be >= 0, got w={self.noise_var_w}, v={self.noise_var_v}",
        )
        check(self.x0_std >= 0, f"system.x0_std must be >= 0, got {self.x0_std}")


@dataclass(frozen=True)
class QuadrotorParams(SystemParams):
    """mass, length, inertia (B,): (m, l, J); C (B, 3, 6); Q (B, 6, 6); R (B, 3, 3); P0 (B, 6, 6);
    x0_mean (B, 6): x_0 ~ N(x0_mean, P0) = N(0, x0_std^2 I) before clipping."""

    mass: Tensor
    length: Tensor
    inertia: Tensor
    C: Tensor
    Q: Tensor
    R: Tensor
    P0: Tensor
    x0_mean: Tensor


@register_family("quadrotor", QuadrotorConfig)
class QuadrotorFamily(SystemFamily):
    """params: QuadrotorParams. Trajectories carry u (B, T+1, 2); u_T is drawn too (the model reads
    [y_t, u_t]) but moves nothing.
    """

    Params = QuadrotorParams
    state_dim, output_dim, input_dim = STATE_DIM, OUTPUT_DIM, INPUT_DIM

    def sample(self, num_systems: int, *, generator: torch.Generator) -> QuadrotorParams:
        B, dev = num_systems, generator.device
        mass, length, inertia = uniform((3, B), *PARAM_RANGE, generator)
        C = uniform((B, OUTPUT_DIM, STATE_DIM), 0.0, 1.0, generator)
        eye = lambda d, var: scaled_eye(B, d, var, dev)  # noqa: E731
        cfg = self.config
        return QuadrotorParams(
            mass=mass,
            length=length,
            inertia=inertia,
            C=C,
            Q=eye(STATE_DIM, cfg.noise_var_w),
            R=eye(OUTPUT_DIM, cfg.noise_var_v),
            P0=eye(STATE_DIM, cfg.x0_std**2),
            x0_mean=torch.zeros(B, STATE_DIM, dtype=torch.float64, device=dev),
        )

    def simulate(self, params: QuadrotorParams, horizon: int, *, generator: torch.Generator) -> Trajectories:
        p = params.map(lambda v: v.to(self.dtype))
        B, cfg = p.C.shape[0], self.config
        u = uniform((B, horizon + 1, INPUT_DIM), *ACTION_RANGE, generator, self.dtype)  # (B, T+1, 2)
        w = normal((B, horizon, STATE_DIM), generator, self.dtype) * cfg.noise_var_w**0.5
        v = normal((B, horizon + 1, OUTPUT_DIM), generator, self.dtype) * cfg.noise_var_v**0.5
        x0 = p.x0_mean + normal((B, STATE_DIM), generator, self.dtype) * cfg.x0_std  # N(x0_mean, P0)
        x = clip_state(x0)  # (B, 6)
        xs = [x]
        for t in range(horizon):
            x = clip_state(dynamics(x, u[:, t], p.mass, p.length, p.inertia) + w[:, t])
            xs.append(x)
        x = torch.stack(xs, dim=1)  # (B, T+1, 6)
        y = x @ p.C.mT + v  # (B, T+1, 3)
        return Trajectories(y=y, u=u, x=x, params=params, family=self.name)

    @staticmethod
    def state_space(params: QuadrotorParams) -> StateSpace:
        """f and its Jacobian with (m, l, J) known, C, Q, R, N(x0_mean, P0), and the clipping (BOUNDS)."""
        p = params.map(Tensor.double)
        mlJ = (p.mass, p.length, p.inertia)  # (B,) each
        return StateSpace(
            f=lambda x, u, t: dynamics(x, u, *(q[:, None] for q in mlJ)),
            C=p.C,
            Q=p.Q,
            R=p.R,
            m0=p.x0_mean,
            P0=p.P0,
            jacobian=lambda x, u, t: dynamics_jacobian(x, u, *mlJ),
            project=clip_state,
        )


__all__ = [
    "QuadrotorFamily",
    "QuadrotorConfig",
    "QuadrotorParams",
    "dynamics",
    "dynamics_jacobian",
    "clip_state",
    "TAU",
    "GRAVITY",
    "BOUNDS",
]
