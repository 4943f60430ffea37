"""A family written outside the package: a damped pendulum driven by a random torque, with random length,
damping and torque gain per system. Importing this file registers it (the experiment file
examples/pendulum.toml names it as a plugin); nothing inside mop/ knows it.

    omega_{t+1} = omega_t + tau (-(g / l) sin(theta_t) - b omega_t + k u_t)        then + w_t
    theta_{t+1} = theta_t + tau omega_{t+1}          (semi-implicit Euler: explicit Euler would gain energy)
    y_t = C x_t + v_t,   x = (theta, omega),   C (2 x 2) entries U[0, 1]

l ~ U[0.5, 2], b ~ U[0.1, 0.5], k ~ U[0.5, 2], u_t ~ U[-1, 1], w ~ N(0, q I), v ~ N(0, r I),
x_0 ~ N(0, x0_std^2 I).
No Jacobian is given: the EKF differentiates f with autograd (StateSpace.jacobian = None).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from mop.errors import check
from mop.systems import StateSpace, SystemConfig, SystemFamily, SystemParams, Trajectories, register_family
from mop.systems.base import normal, scaled_eye, uniform

TAU, GRAVITY = 0.1, 9.81


@dataclass(frozen=True)
class PendulumConfig(SystemConfig):
    family: str = "pendulum"
    noise_var_w: float = 1e-3
    noise_var_v: float = 1e-2
    x0_std: float = 0.5

    def __post_init__(self) -> None:
        super().__post_init__()
        check(self.noise_var_w >= 0 and self.noise_var_v >= 0, "pendulum: noise variances must be >= 0")
        check(self.x0_std >= 0, f"pendulum: x0_std must be >= 0, got {self.x0_std}")


def step(x: Tensor, u: Tensor, length: Tensor, damping: Tensor, gain: Tensor) -> Tensor:
    """x (..., 2), u (..., 1), parameters broadcastable to (...,) -> next state (..., 2), noise-free."""
    theta, omega = x.unbind(-1)
    accel = -(GRAVITY / length) * torch.sin(theta) - damping * omega + gain * u[..., 0]
    omega_next = omega + TAU * accel  # semi-implicit Euler: the angle moves with the new rate, so the
    return torch.stack([theta + TAU * omega_next, omega_next], dim=-1)  # damped swing decays (det 1 - tau b)


@dataclass(frozen=True)
class PendulumParams(SystemParams):
    """length, damping, gain (B,): (l, b, k); C (B, 2, 2); Q, R, P0 (B, 2, 2); x0_mean (B, 2)."""

    length: Tensor
    damping: Tensor
    gain: Tensor
    C: Tensor
    Q: Tensor
    R: Tensor
    P0: Tensor
    x0_mean: Tensor


@register_family("pendulum", PendulumConfig)
class PendulumFamily(SystemFamily):
    """params: PendulumParams."""

    Params = PendulumParams
    state_dim, output_dim, input_dim = 2, 2, 1

    def sample(self, num_systems: int, *, generator: torch.Generator) -> PendulumParams:
        B, dev, cfg = num_systems, generator.device, self.config
        length = uniform((B,), 0.5, 2.0, generator)
        damping = uniform((B,), 0.1, 0.5, generator)
        gain = uniform((B,), 0.5, 2.0, generator)
        return PendulumParams(
            length=length,
            damping=damping,
            gain=gain,
            C=uniform((B, 2, 2), 0.0, 1.0, generator),
            Q=scaled_eye(B, 2, cfg.noise_var_w, dev),
            R=scaled_eye(B, 2, cfg.noise_var_v, dev),
            P0=scaled_eye(B, 2, cfg.x0_std**2, dev),
            x0_mean=torch.zeros(B, 2, dtype=torch.float64, device=dev),
        )

    def simulate(self, params: PendulumParams, horizon: int, *, generator: torch.Generator) -> Trajectories:
        p, cfg = params.map(lambda v: v.to(self.dtype)), self.config
        B = p.C.shape[0]
        u = uniform((B, horizon + 1, 1), -1.0, 1.0, generator, self.dtype)  # (B, T+1, 1)
        w = normal((B, horizon, 2), generator, self.dtype) * cfg.noise_var_w**0.5
        v = normal((B, horizon + 1, 2), generator, self.dtype) * cfg.noise_var_v**0.5
        x = p.x0_mean + normal((B, 2), generator, self.dtype) * cfg.x0_std
        xs = [x]
        for t in range(horizon):
            x = step(x, u[:, t], p.length, p.damping, p.gain) + w[:, t]
            xs.append(x)
        x = torch.stack(xs, dim=1)  # (B, T+1, 2)
        return Trajectories(y=x @ p.C.mT + v, u=u, x=x, params=params, family=self.name)

    @staticmethod
    def state_space(params: PendulumParams) -> StateSpace:
        p = params.map(Tensor.double)
        lbk = tuple(q[:, None] for q in (p.length, p.damping, p.gain))  # (B, 1): broadcast over point sets
        return StateSpace(f=lambda x, u, t: step(x, u, *lbk), C=p.C, Q=p.Q, R=p.R, m0=p.x0_mean, P0=p.P0)
