"""A family written outside the package, with one known input: two masses on springs and dampers driven by
one random force, a mechanical system. Importing this file registers it as "two-mass"
(examples/two_mass.toml names it as a plugin).

Continuous time, positions p1, p2 [m] and velocities v1, v2 [m/s] of two masses in a line: a spring k1 and a
damper c1 tie mass 1 to the wall, a spring k2 and a damper c2 tie mass 2 to mass 1; the force u(t) [N]
pushes mass 1, disturbance forces e1(t), e2(t) [N] act on both:

    m1 dv1/dt = -k1 p1 - c1 v1 + k2 (p2 - p1) + c2 (v2 - v1) + u + e1,
    m2 dv2/dt = -k2 (p2 - p1) - c2 (v2 - v1) + e2,    i.e.  dx/dt = A_c x + b u + G e,  x = (p1, p2, v1, v2).

The force is held over each sample period dt (zero-order hold), so the exact discrete model is

    x_{t+1} = A x_t + B u_t + w_t,   [[A, B], [0, 1]] = expm([[A_c, b], [0, 0]] dt)   (scipy.linalg.expm),
    w_t ~ N(0, Q),   Q = int_0^dt expm(A_c s) G G^T expm(A_c s)^T ds,  G = q [[0, 0], [0, 0], [1/m1, 0],
    [0, 1/m2]]  (Van Loan's block expm),   y_t = (p1, p2) + v_t,   v_t ~ N(0, r^2 I),

e continuous white noise of intensity q^2 (q = disturbance_std), r = sensor_std. Ranges (log-uniform per
system): masses in [0.5, 2] kg, springs in [0.5, 5] N/m, dampers in [0.05, 1] N s/m, dt = 0.2 s: natural
frequencies from about 0.3 to 3.5 rad/s, so 2 to 20 samples a period, damping from light to heavy.
u_t ~ N(0, force_std^2) i.i.d.; x_0 ~ N(0, initial_std^2 I). The Kalman filter that knows
(A, B, C, Q, R, P0) is the optimal one-step predictor. n = 4, m = 2, k = 1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from scipy.linalg import expm
from torch import Tensor

from mop.errors import check
from mop.systems import SystemConfig, SystemFamily, SystemParams, Trajectories, register_family
from mop.systems.base import StateSpace, linear_state_space, normal, uniform
from mop.systems.linear import simulate_linear

RANGES = ("mass", "spring", "damper")


@dataclass(frozen=True)
class TwoMassConfig(SystemConfig):
    """Log-uniform ranges [*_min, *_max] of the masses, springs and dampers; dt (s); the force's std (N);
    the disturbance forces' intensity; the position sensors' std (m); the initial state's std. No knob
    shares a name with a built-in family's (see rlc_circuit.py)."""

    family: str = "two-mass"
    mass_min: float = 0.5
    mass_max: float = 2.0
    spring_min: float = 0.5
    spring_max: float = 5.0
    damper_min: float = 0.05
    damper_max: float = 1.0
    dt: float = 0.2
    force_std: float = 1.0
    disturbance_std: float = 0.3
    sensor_std: float = 0.1
    initial_std: float = 0.5

    def bounds(self, name: str) -> tuple[float, float]:
        """(low, high) of "mass", "spring" or "damper"."""
        return getattr(self, f"{name}_min"), getattr(self, f"{name}_max")

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in RANGES:
            low, high = self.bounds(name)
            check(0 < low <= high, f"two-mass: {name} must be a range 0 < low <= high, not {[low, high]}")
        check(self.dt > 0, f"two-mass: dt must be > 0 seconds, got {self.dt}")
        for name in ("force_std", "disturbance_std", "sensor_std", "initial_std"):
            value = getattr(self, name)
            check(value >= 0, f"two-mass: {name} must be >= 0, got {value}")


def continuous_model(m: np.ndarray, k: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """m, k, c (B, 2) -> A_c (B, 4, 4), b (B, 4, 1) of dx/dt = A_c x + b u, x = (p1, p2, v1, v2)."""
    B = m.shape[0]
    K = np.zeros((B, 2, 2))
    K[:, 0, 0], K[:, 0, 1], K[:, 1, 0], K[:, 1, 1] = k[:, 0] + k[:, 1], -k[:, 1], -k[:, 1], k[:, 1]
    D = np.zeros((B, 2, 2))
    D[:, 0, 0], D[:, 0, 1], D[:, 1, 0], D[:, 1, 1] = c[:, 0] + c[:, 1], -c[:, 1], -c[:, 1], c[:, 1]
    A_c = np.zeros((B, 4, 4))
    A_c[:, :2, 2:] = np.eye(2)
    A_c[:, 2:, :2], A_c[:, 2:, 2:] = -K / m[:, :, None], -D / m[:, :, None]
    b = np.zeros((B, 4, 1))
    b[:, 2, 0] = 1 / m[:, 0]
    return A_c, b


def discretize(A_c: np.ndarray, b: np.ndarray, G: np.ndarray, dt: float) -> tuple[np.ndarray, ...]:
    """A, B by zero-order hold and Q = int_0^dt expm(A_c s) G G^T expm(A_c s)^T ds (Van Loan), each from
    one scipy.linalg.expm of a block matrix. A_c (B, n, n), b (B, n, 1), G (B, n, g)."""
    B, n = A_c.shape[:2]
    M = np.zeros((B, n + 1, n + 1))
    M[:, :n, :n], M[:, :n, n:] = A_c * dt, b * dt
    E = expm(M)
    V = np.zeros((B, 2 * n, 2 * n))
    V[:, :n, :n], V[:, n:, n:] = -A_c * dt, A_c.transpose(0, 2, 1) * dt
    V[:, :n, n:] = G @ G.transpose(0, 2, 1) * dt
    F = expm(V)
    Q = F[:, n:, n:].transpose(0, 2, 1) @ F[:, :n, n:]
    return E[:, :n, :n], E[:, :n, n:], (Q + Q.transpose(0, 2, 1)) / 2


def log_uniform(shape: tuple[int, ...], bounds: tuple[float, float], generator: torch.Generator) -> Tensor:
    return uniform(shape, math.log(bounds[0]), math.log(bounds[1]), generator).exp()


@dataclass(frozen=True)
class TwoMassParams(SystemParams):
    """mass, spring, damper (B, 2); the exact discrete model A (B, 4, 4), B (B, 4, 1), C (B, 2, 4),
    Q (B, 4, 4), R (B, 2, 2), P0 (B, 4, 4), x0_mean (B, 4); float64."""

    mass: Tensor
    spring: Tensor
    damper: Tensor
    A: Tensor
    B: Tensor
    C: Tensor
    Q: Tensor
    R: Tensor
    P0: Tensor
    x0_mean: Tensor


@register_family("two-mass", TwoMassConfig)
class TwoMassFamily(SystemFamily):
    """params: TwoMassParams."""

    Params = TwoMassParams
    state_dim, output_dim, input_dim = 4, 2, 1

    def sample(self, num_systems: int, *, generator: torch.Generator) -> TwoMassParams:
        cfg, B = self.config, num_systems
        m, k, c = (log_uniform((B, 2), cfg.bounds(name), generator) for name in RANGES)
        A_c, b = continuous_model(m.cpu().numpy(), k.cpu().numpy(), c.cpu().numpy())
        G = np.zeros((B, 4, 2))
        G[:, 2, 0], G[:, 3, 1] = 1 / m[:, 0].cpu().numpy(), 1 / m[:, 1].cpu().numpy()
        A, Bd, Q = (
            torch.from_numpy(a).to(m.device) for a in discretize(A_c, b, G * cfg.disturbance_std, cfg.dt)
        )
        eye = lambda d: torch.eye(d, dtype=torch.float64, device=m.device).expand(B, d, d).clone()  # noqa: E731
        return TwoMassParams(
            mass=m,
            spring=k,
            damper=c,
            A=A,
            B=Bd,
            C=eye(4)[:, :2].clone(),
            Q=Q,
            R=cfg.sensor_std**2 * eye(2),
            P0=cfg.initial_std**2 * eye(4),
            x0_mean=torch.zeros(B, 4, dtype=torch.float64, device=m.device),
        )

    def simulate(self, params: TwoMassParams, horizon: int, *, generator: torch.Generator) -> Trajectories:
        cfg = self.config
        A, Bd, C = (M.to(self.dtype) for M in (params.A, params.B, params.C))
        num = A.shape[0]
        lam, V = torch.linalg.eigh(params.Q)
        w_root = (V * lam.clamp(min=0).sqrt()[..., None, :]).to(self.dtype)  # (B, 4, 4), w_root w_root^T = Q
        x0 = normal((num, 4), generator, self.dtype) * cfg.initial_std
        u = normal((num, horizon + 1, 1), generator, self.dtype) * cfg.force_std  # (B, T+1, 1)
        w = normal((num, horizon + 1, 4), generator, self.dtype) @ w_root.mT  # (B, T+1, 4), w_T unused
        v = normal((num, horizon + 1, 2), generator, self.dtype) * cfg.sensor_std
        x, y = simulate_linear(A, C, x0, w + u @ Bd.mT, v)  # the force enters as the known forcing B u_t
        return Trajectories(y=y, u=u, x=x, params=params, family=self.name)

    @staticmethod
    def state_space(params: TwoMassParams) -> StateSpace:
        """x_{t+1} = A x_t + B u_t + w_t, y_t = C x_t + v_t, x_0 ~ N(0, P0)."""
        p = params
        return linear_state_space(p.A, p.C, p.Q, p.R, p.P0, B=p.B, m0=p.x0_mean)
