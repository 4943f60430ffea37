"""A family written outside the package, with one known input: a coupled thermal network (a chain of
rooms or components with random heat capacities and conductances) heated by one random heater. Importing
this file registers it as "thermal-network" (examples/thermal_network.toml names it as a plugin).

Continuous time, state x = temperature deviations of the n nodes from ambient [K], heater power u(t) [W]
into node 1, heat-flow disturbances e(t) [W] into every node:

    c_i dx_i/dt = - g_i x_i - sum_j k_ij (x_i - x_j) + [i = 1] u + e_i,   i.e.  dx/dt = A_c x + b u + c^-1 e,
    A_c = -diag(c)^-1 (diag(g) + L),   b = e_1 / c_1,

with c_i [J/K] the heat capacities, g_i [W/K] the conductances to ambient and L the Laplacian of the chain
1 - 2 - ... - n with coupling conductances k_{i,i+1} [W/K] (L_ii = sum_j k_ij, L_ij = -k_ij). A_c is
similar to the symmetric -c^-1/2 (diag(g) + L) c^-1/2, so its eigenvalues are real and negative: every
node relaxes to ambient, the slowest with the time constant 1 / |lambda_max|.

The heater is held constant over each sample period dt (zero-order hold), so the exact discrete model is

    x_{t+1} = A x_t + B u_t + w_t,   [[A, B], [0, 1]] = expm([[A_c, b], [0, 0]] dt)   (scipy.linalg.expm),
    w_t ~ N(0, Q),   Q = int_0^dt expm(A_c s) G G^T expm(A_c s)^T ds,  G = q diag(c)^-1   (Van Loan's block
    expm, scipy.linalg.expm),
    y_t = C x_t + v_t,  v_t ~ N(0, r^2 I),   C = rows e_1 and e_n: sensors on the heated and the far node,

with e(t) continuous white noise of intensity q^2 per node (q = disturbance_std) and r = sensor_std [K].
Ranges (log-uniform per system):
c_i in [1, 10], g_i in [0.05, 0.5], k_{i,i+1} in [0.2, 2], dt = 1 (one unit of time per sample): time
constants c / g from 2 to 200 samples, so some networks forget in a few steps and some integrate the heater
over the whole trajectory (their outputs are far larger: the family's per-system output RMS spans more than
a decade). Heater u_t ~ N(0, heater_std^2) i.i.d. (power deviations around an operating point, white so
persistently exciting). Initial state x_0 ~ N(0, initial_std^2 I). The Kalman filter that knows
(A, B, C, Q, R, P0) is the optimal one-step predictor (its time update is m <- A m + B u_t).
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


@dataclass(frozen=True)
class ThermalConfig(SystemConfig):
    """num_nodes n; log-uniform ranges [*_min, *_max] of the heat capacities c_i, the conductances to
    ambient g_i and the couplings k_{i,i+1}; dt; the heater's std; the disturbance's and the sensors' std;
    the initial temperatures' std. No knob shares a name with a built-in family's (see rlc_circuit.py)."""

    family: str = "thermal-network"
    num_nodes: int = 4
    capacity_min: float = 1.0
    capacity_max: float = 10.0
    ambient_min: float = 0.05
    ambient_max: float = 0.5
    coupling_min: float = 0.2
    coupling_max: float = 2.0
    dt: float = 1.0
    heater_std: float = 1.0
    disturbance_std: float = 0.1
    sensor_std: float = 0.1
    initial_std: float = 1.0

    def bounds(self, name: str) -> tuple[float, float]:
        """(low, high) of "capacity", "ambient" or "coupling"."""
        return getattr(self, f"{name}_min"), getattr(self, f"{name}_max")

    def __post_init__(self) -> None:
        super().__post_init__()
        check(
            isinstance(self.num_nodes, int) and 2 <= self.num_nodes <= 20,
            f"thermal-network: num_nodes must be an integer in 2..20, got {self.num_nodes!r}",
        )
        for name in ("capacity", "ambient", "coupling"):
            low, high = self.bounds(name)
            check(
                0 < low <= high, f"thermal-network: {name} must be a range 0 < low <= high, not {[low, high]}"
            )
        check(self.dt > 0, f"thermal-network: dt must be > 0, got {self.dt}")
        for name in ("heater_std", "disturbance_std", "sensor_std", "initial_std"):
            value = getattr(self, name)
            check(value >= 0, f"thermal-network: {name} must be >= 0, got {value}")


def continuous_model(c: np.ndarray, g: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """c, g (B, n), k (B, n-1) -> A_c (B, n, n), b (B, n, 1) of dx/dt = A_c x + b u (heater at node 1)."""
    B, n = c.shape
    L = np.zeros((B, n, n))
    i = np.arange(n - 1)
    L[:, i, i + 1] = L[:, i + 1, i] = -k
    L[:, i, i] += k
    L[:, i + 1, i + 1] += k
    A_c = -(L + g[:, :, None] * np.eye(n)) / c[:, :, None]
    b = np.zeros((B, n, 1))
    b[:, 0, 0] = 1 / c[:, 0]
    return A_c, b


def discretize(A_c: np.ndarray, b: np.ndarray, G: np.ndarray, dt: float) -> tuple[np.ndarray, ...]:
    """A, B by zero-order hold and Q = int_0^dt expm(A_c s) G G^T expm(A_c s)^T ds (Van Loan), each from
    one scipy.linalg.expm of a block matrix. A_c (B, n, n), b (B, n, 1), G (B, n, n)."""
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


def psd_sqrt(Q: Tensor) -> Tensor:
    """S (B, n, n) with S S^T = Q for symmetric Q >= 0."""
    lam, V = torch.linalg.eigh(Q)
    return V * lam.clamp(min=0).sqrt()[..., None, :]


@dataclass(frozen=True)
class ThermalParams(SystemParams):
    """capacity, ambient (B, n), coupling (B, n-1); the exact discrete model A (B, n, n), B (B, n, 1),
    C (B, 2, n), Q (B, n, n), R (B, 2, 2), P0 (B, n, n), x0_mean (B, n); float64."""

    capacity: Tensor
    ambient: Tensor
    coupling: Tensor
    A: Tensor
    B: Tensor
    C: Tensor
    Q: Tensor
    R: Tensor
    P0: Tensor
    x0_mean: Tensor


@register_family("thermal-network", ThermalConfig)
class ThermalFamily(SystemFamily):
    """params: ThermalParams."""

    Params = ThermalParams
    output_dim, input_dim = 2, 1

    def __init__(self, config: ThermalConfig, dtype: torch.dtype = torch.float32) -> None:
        super().__init__(config, dtype)
        self.state_dim = config.num_nodes

    def sample(self, num_systems: int, *, generator: torch.Generator) -> ThermalParams:
        cfg, B, n = self.config, num_systems, self.config.num_nodes
        c = log_uniform((B, n), cfg.bounds("capacity"), generator)
        g = log_uniform((B, n), cfg.bounds("ambient"), generator)
        k = log_uniform((B, n - 1), cfg.bounds("coupling"), generator)
        A_c, b = continuous_model(c.cpu().numpy(), g.cpu().numpy(), k.cpu().numpy())
        G = np.eye(n) / c.cpu().numpy()[:, :, None] * cfg.disturbance_std  # heat-flow noise into each node
        A, Bd, Q = (torch.from_numpy(a).to(c.device) for a in discretize(A_c, b, G, cfg.dt))
        C = torch.zeros(B, 2, n, dtype=torch.float64, device=c.device)
        C[:, 0, 0], C[:, 1, n - 1] = 1.0, 1.0
        eye = lambda d: torch.eye(d, dtype=torch.float64, device=c.device).expand(B, d, d).clone()  # noqa: E731
        return ThermalParams(
            capacity=c,
            ambient=g,
            coupling=k,
            A=A,
            B=Bd,
            C=C,
            Q=Q,
            R=cfg.sensor_std**2 * eye(2),
            P0=cfg.initial_std**2 * eye(n),
            x0_mean=torch.zeros(B, n, dtype=torch.float64, device=c.device),
        )

    def simulate(self, params: ThermalParams, horizon: int, *, generator: torch.Generator) -> Trajectories:
        cfg, n = self.config, self.state_dim
        A, Bd, C = (M.to(self.dtype) for M in (params.A, params.B, params.C))
        num = A.shape[0]
        w_root = psd_sqrt(params.Q).to(self.dtype)  # (B, n, n)
        x0 = normal((num, n), generator, self.dtype) * cfg.initial_std
        u = normal((num, horizon + 1, 1), generator, self.dtype) * cfg.heater_std  # (B, T+1, 1)
        w = normal((num, horizon + 1, n), generator, self.dtype) @ w_root.mT  # (B, T+1, n), w_T unused
        v = normal((num, horizon + 1, 2), generator, self.dtype) * cfg.sensor_std
        x, y = simulate_linear(A, C, x0, w + u @ Bd.mT, v)  # the heater enters as the known forcing B u_t
        return Trajectories(y=y, u=u, x=x, params=params, family=self.name)

    @staticmethod
    def state_space(params: ThermalParams) -> StateSpace:
        """x_{t+1} = A x_t + B u_t + w_t, y_t = C x_t + v_t, x_0 ~ N(0, P0)."""
        p = params
        return linear_state_space(p.A, p.C, p.Q, p.R, p.P0, B=p.B, m0=p.x0_mean)
