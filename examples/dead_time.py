"""A family written outside the package, with one known input: a second-order plant with a
non-minimum-phase zero behind an input dead time of 1 to max_delay samples, all random per system.
Importing this file registers it as "dead-time" (examples/dead_time.toml names it as a plugin).

Transfer function from the input u to the noise-free output (z the shift operator):

    G(z) = K (z - z0) / ((z - p1) (z - p2)) z^-d,      K = (1 - p1) (1 - p2) / (1 - z0)  (DC gain 1),

with the poles p1, p2 a complex pair r e^{+-i theta} (r ~ U[pole_radius_min, pole_radius_max],
theta ~ U[0, max_angle]), the zero z0 ~ U[zero_min, zero_max] outside the unit circle (a non-minimum-phase
plant: a step first moves the output the wrong way, and no stable inverse exists) and the dead time
d ~ U{1..max_delay}. State space (controllable canonical form of the plant, then the input's delay line):

    s_t = [x_t (2); u_{t-1}; ...; u_{t-D}]  (n = 2 + D, D = max_delay),
    x_{t+1} = [[a1, a2], [1, 0]] x_t + [1, 0]^T u_{t-d} + w_t,   a1 = p1 + p2, a2 = -p1 p2,
    y_t = K [1, -z0] x_t + v_t,

i.e. s_{t+1} = A s_t + B u_t + [w_t; 0], A = [[A_x, e_1 e_d^T], [0, S]] with S the delay line's shift and
B = e_3 (u_t enters the line). w_t ~ N(0, process_std^2 I_2), v_t ~ N(0, output_std^2), x_0 ~ N(0,
initial_std^2 I_2), the line starts empty (u_t = 0 before t = 0, known: its P0 block is 0). u_t ~ N(0, 1)
i.i.d. The Kalman filter that knows (A, B, C, Q, R, P0), dead time included, is the optimal one-step
predictor; ARX needs input lags up to d + 2 to represent the plant.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from mop.errors import check
from mop.systems import SystemConfig, SystemFamily, SystemParams, Trajectories, register_family
from mop.systems.base import StateSpace, linear_state_space, normal, uniform
from mop.systems.linear import simulate_linear


@dataclass(frozen=True)
class DeadTimeConfig(SystemConfig):
    """The poles' radius range and largest angle (rad), the zero's range (> 1: non-minimum phase), the
    largest dead time D (samples; d ~ U{1..D}), the process, output and initial-state noise stds."""

    family: str = "dead-time"
    pole_radius_min: float = 0.5
    pole_radius_max: float = 0.95
    max_angle: float = math.pi / 2
    zero_min: float = 1.25
    zero_max: float = 4.0
    max_delay: int = 3
    process_std: float = 0.1
    output_std: float = 0.1
    initial_std: float = 1.0

    def __post_init__(self) -> None:
        super().__post_init__()
        check(
            0 <= self.pole_radius_min <= self.pole_radius_max < 1,
            "dead-time: pole radii must satisfy 0 <= min <= max < 1 (a stable plant), got "
            f"{[self.pole_radius_min, self.pole_radius_max]}",
        )
        check(0 <= self.max_angle <= math.pi, f"dead-time: max_angle is in [0, pi], not {self.max_angle}")
        check(
            1 < self.zero_min <= self.zero_max,
            f"dead-time: the zero's range must satisfy 1 < min <= max, got {[self.zero_min, self.zero_max]}",
        )
        check(
            isinstance(self.max_delay, int) and 1 <= self.max_delay <= 10,
            f"dead-time: max_delay must be an integer in 1..10, got {self.max_delay!r}",
        )
        for name in ("process_std", "output_std", "initial_std"):
            check(getattr(self, name) >= 0, f"dead-time: {name} must be >= 0, got {getattr(self, name)}")


@dataclass(frozen=True)
class DeadTimeParams(SystemParams):
    """radius, angle, zero, gain (B,), delay (B,) integers 1..D; the augmented linear model A (B, n, n),
    B (B, n, 1), C (B, 1, n), Q (B, n, n), R (B, 1, 1), P0 (B, n, n), x0_mean (B, n), n = 2 + D; float64."""

    radius: Tensor
    angle: Tensor
    zero: Tensor
    gain: Tensor
    delay: Tensor
    A: Tensor
    B: Tensor
    C: Tensor
    Q: Tensor
    R: Tensor
    P0: Tensor
    x0_mean: Tensor


@register_family("dead-time", DeadTimeConfig)
class DeadTimeFamily(SystemFamily):
    """params: DeadTimeParams."""

    Params = DeadTimeParams
    output_dim, input_dim = 1, 1

    def __init__(self, config: DeadTimeConfig, dtype: torch.dtype = torch.float32) -> None:
        super().__init__(config, dtype)
        self.state_dim = 2 + config.max_delay

    def sample(self, num_systems: int, *, generator: torch.Generator) -> DeadTimeParams:
        cfg, B, D, n = self.config, num_systems, self.config.max_delay, self.state_dim
        r = uniform((B,), cfg.pole_radius_min, cfg.pole_radius_max, generator)
        theta = uniform((B,), 0.0, cfg.max_angle, generator)
        z0 = uniform((B,), cfg.zero_min, cfg.zero_max, generator)
        delay = (uniform((B,), 0.0, 1.0, generator) * D).floor().long().clamp(max=D - 1) + 1  # U{1..D}
        a1, a2 = 2 * r * theta.cos(), -(r**2)
        gain = (1 - a1 - a2) / (1 - z0)  # (1 - p1)(1 - p2) = 1 - a1 - a2
        A = torch.zeros(B, n, n, dtype=torch.float64, device=r.device)
        A[:, 0, 0], A[:, 0, 1], A[:, 1, 0] = a1, a2, 1.0
        A[torch.arange(B), 0, 1 + delay] = 1.0  # x1 reads u_{t-d}, slot 2 + d - 1 of the line
        line = torch.arange(2, n - 1)
        A[:, line + 1, line] = 1.0  # the line shifts: u_{t-j} -> slot of u_{t-j-1}
        Bd = torch.zeros(B, n, 1, dtype=torch.float64, device=r.device)
        Bd[:, 2, 0] = 1.0
        C = torch.zeros(B, 1, n, dtype=torch.float64, device=r.device)
        C[:, 0, 0], C[:, 0, 1] = gain, -gain * z0
        Q = torch.zeros(B, n, n, dtype=torch.float64, device=r.device)
        Q[:, 0, 0] = Q[:, 1, 1] = cfg.process_std**2
        P0 = torch.zeros_like(Q)
        P0[:, 0, 0] = P0[:, 1, 1] = cfg.initial_std**2
        R = torch.full((B, 1, 1), cfg.output_std**2, dtype=torch.float64, device=r.device)
        x0_mean = torch.zeros(B, n, dtype=torch.float64, device=r.device)
        plant = {"radius": r, "angle": theta, "zero": z0, "gain": gain, "delay": delay}
        return DeadTimeParams(**plant, A=A, B=Bd, C=C, Q=Q, R=R, P0=P0, x0_mean=x0_mean)

    def simulate(self, params: DeadTimeParams, horizon: int, *, generator: torch.Generator) -> Trajectories:
        cfg, n = self.config, self.state_dim
        A, Bd, C = (M.to(self.dtype) for M in (params.A, params.B, params.C))
        num = A.shape[0]
        x0 = torch.zeros(num, n, dtype=self.dtype, device=A.device)
        x0[:, :2] = normal((num, 2), generator, self.dtype) * cfg.initial_std
        u = normal((num, horizon + 1, 1), generator, self.dtype)  # (B, T+1, 1)
        w = torch.zeros(num, horizon + 1, n, dtype=self.dtype, device=A.device)
        w[..., :2] = normal((num, horizon + 1, 2), generator, self.dtype) * cfg.process_std
        v = normal((num, horizon + 1, 1), generator, self.dtype) * cfg.output_std
        x, y = simulate_linear(A, C, x0, w + u @ Bd.mT, v)  # u_t enters the delay line as B u_t
        return Trajectories(y=y, u=u, x=x, params=params, family=self.name)

    @staticmethod
    def state_space(params: DeadTimeParams) -> StateSpace:
        """s_{t+1} = A s_t + B u_t + w_t, y_t = C s_t + v_t, s_0 ~ N(0, P0) (the line's block of P0 is 0)."""
        p = params
        return linear_state_space(p.A, p.C, p.Q, p.R, p.P0, B=p.B, m0=p.x0_mean)
