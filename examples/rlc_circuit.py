"""A family written outside the package, with known inputs: a series RLC circuit driven by a random source
voltage, with random resistance, inductance and capacitance per system. Importing this file registers it
as "rlc-circuit" (the experiment file examples/rlc_circuit.toml names it as a plugin); nothing inside mop/
knows it.

Continuous time, state x = (v_C [V], i_L [A]), source voltage u(t) [V], disturbance voltage e(t) [V] in
series with the source (white, two-sided power spectral density disturbance_std^2 * dt [V^2 s]):

    C dv_C/dt = i_L
    L di_L/dt = u + e - R i_L - v_C           i.e.   dx/dt = A_c x + b (u + e),
    A_c = [[0, 1/C], [-1/L, -R/L]],  b = [0, 1/L]^T.

The source is held constant over each sample period dt (zero-order hold: u(t) = u_t on [t dt, (t+1) dt)),
so the exact discrete-time model is

    x_{t+1} = A x_t + B u_t + w_t,   A = expm(A_c dt),  B = int_0^dt expm(A_c s) ds b,
    w_t ~ N(0, Q),   Q = disturbance_std^2 dt int_0^dt expm(A_c s) b b^T expm(A_c s)^T ds   (Van Loan),
    y_t = C x_t + v_t,   v_t ~ N(0, output_std^2 I),

with A, B from one matrix exponential of the augmented [[A_c, b], [0, 0]] dt and Q from Van Loan's
[[-A_c, b b^T], [0, A_c^T]] dt. Outputs (volts): output = "both" measures the capacitor voltage and the
voltage across the resistor, y = (v_C, R i_L), C = [[1, 0], [0, R]]; output = "capacitor" measures v_C
alone, C = [[1, 0]].

Ranges (log-uniform per system): R in [10, 100] Ohm, L in [20, 200] mH, C in [20, 200] uF, dt = 1 ms.
Then omega_0 dt = dt / sqrt(L C) lies in [0.16, 1.6], the damping ratio zeta = (R / 2) sqrt(C / L) in
[0.06, 4.6] (ringing to overdamped) and the spectral radius of A in about [0.23, 0.975] (median 0.83):
stable, yet slow enough that the past matters for ~5 to 40 steps.
Source u_t ~ N(0, input_std^2) i.i.d. (white, so persistently exciting), drawn for t = 0..T (u_T moves
nothing). Initial state x_0 ~ N(0, P0), P0 = s^2 diag(1, C / L), s = initial_voltage_std: on average as
much energy in the inductor as in the capacitor. The Kalman filter that knows (A, B, C, Q, R, P0) is the
optimal one-step predictor (its time update is m <- A m + B u_t).
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

OUTPUTS = {"both": 2, "capacitor": 1}


@dataclass(frozen=True)
class RLCConfig(SystemConfig):
    """Ranges [*_min, *_max] of R (Ohm), L (H), C (F), each drawn log-uniform; dt (s); the source's std (V);
    the disturbance voltage's per-sample std (V); the voltmeters' std (V); the initial v_C's std (V);
    output ("both" or "capacitor").

    No knob shares a name with the built-in "linear" family's (x0_std, noise_var_w, ...): switching a
    config from "linear" to this family keeps the values of shared knobs (mop.config.apply_settings), so
    a shared name would silently take linear's value instead of this default. The ranges are pairs of
    floats, not tuples: a tuple is saved as a JSON list and a rerun then refuses to reuse the trained run
    (the saved list differs from the tuple)."""

    family: str = "rlc-circuit"
    resistance_min: float = 10.0
    resistance_max: float = 100.0
    inductance_min: float = 20e-3
    inductance_max: float = 200e-3
    capacitance_min: float = 20e-6
    capacitance_max: float = 200e-6
    dt: float = 1e-3
    input_std: float = 1.0
    disturbance_std: float = 0.3
    output_std: float = 0.1
    initial_voltage_std: float = 0.5
    output: str = "both"

    def bounds(self, name: str) -> tuple[float, float]:
        """(low, high) of "resistance", "inductance" or "capacitance"."""
        return getattr(self, f"{name}_min"), getattr(self, f"{name}_max")

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("resistance", "inductance", "capacitance"):
            low, high = self.bounds(name)
            check(0 < low <= high, f"rlc-circuit: {name} must be a range 0 < low <= high, got {[low, high]}")
        check(self.dt > 0, f"rlc-circuit: dt must be > 0 seconds, got {self.dt}")
        for name in ("input_std", "disturbance_std", "output_std", "initial_voltage_std"):
            check(getattr(self, name) >= 0, f"rlc-circuit: {name} must be >= 0, got {getattr(self, name)}")
        check(self.output in OUTPUTS, f"rlc-circuit: output is 'both' or 'capacitor', not {self.output!r}")


def continuous_model(R: Tensor, L: Tensor, C: Tensor) -> tuple[Tensor, Tensor]:
    """R, L, C (B,) -> A_c (B, 2, 2) [1/s], b (B, 2, 1) [1/H] of dx/dt = A_c x + b u, x = (v_C, i_L)."""
    zero = torch.zeros_like(R)
    A = torch.stack([torch.stack([zero, 1 / C], -1), torch.stack([-1 / L, -R / L], -1)], -2)
    b = torch.stack([zero, 1 / L], -1)[..., None]
    return A, b


def zoh(A_c: Tensor, b: Tensor, dt: float) -> tuple[Tensor, Tensor]:
    """Exact zero-order-hold discretization: expm([[A_c, b], [0, 0]] dt) = [[A, B], [0, I]].
    A_c (B, n, n), b (B, n, k) -> A (B, n, n), B (B, n, k)."""
    n, k = b.shape[-2:]
    M = torch.zeros(*A_c.shape[:-2], n + k, n + k, dtype=A_c.dtype, device=A_c.device)
    M[..., :n, :n], M[..., :n, n:] = A_c * dt, b * dt
    E = torch.linalg.matrix_exp(M)
    return E[..., :n, :n], E[..., :n, n:]


def van_loan(A_c: Tensor, G: Tensor, dt: float) -> Tensor:
    """Q = int_0^dt expm(A_c s) G G^T expm(A_c s)^T ds (B, n, n), from expm([[-A_c, G G^T], [0, A_c^T]] dt)
    = [[., F12], [0, F22]]: Q = F22^T F12 (Van Loan 1978). A_c (B, n, n), G (B, n, k)."""
    n = A_c.shape[-1]
    M = torch.zeros(*A_c.shape[:-2], 2 * n, 2 * n, dtype=A_c.dtype, device=A_c.device)
    M[..., :n, :n], M[..., :n, n:], M[..., n:, n:] = -A_c * dt, G @ G.mT * dt, A_c.mT * dt
    E = torch.linalg.matrix_exp(M)
    Q = E[..., n:, n:].mT @ E[..., :n, n:]
    return (Q + Q.mT) / 2


def psd_sqrt(Q: Tensor) -> Tensor:
    """S (B, n, n) with S S^T = Q for symmetric Q >= 0 (eigh: Q may be 0 or nearly singular)."""
    lam, V = torch.linalg.eigh(Q)
    return V * lam.clamp(min=0).sqrt()[..., None, :]


def log_uniform(shape: tuple[int, ...], bounds: tuple[float, float], generator: torch.Generator) -> Tensor:
    low, high = math.log(bounds[0]), math.log(bounds[1])
    return uniform(shape, low, high, generator).exp()


@dataclass(frozen=True)
class RLCParams(SystemParams):
    """resistance, inductance, capacitance (B,); the exact discrete model A (B, 2, 2), B (B, 2, 1),
    C (B, m, 2), Q (B, 2, 2), R (B, m, m), P0 (B, 2, 2), x0_mean (B, 2); float64."""

    resistance: Tensor
    inductance: Tensor
    capacitance: Tensor
    A: Tensor
    B: Tensor
    C: Tensor
    Q: Tensor
    R: Tensor
    P0: Tensor
    x0_mean: Tensor


@register_family("rlc-circuit", RLCConfig)
class RLCFamily(SystemFamily):
    """params: RLCParams."""

    Params = RLCParams
    state_dim, input_dim = 2, 1

    def __init__(self, config: RLCConfig, dtype: torch.dtype = torch.float32) -> None:
        super().__init__(config, dtype)
        self.output_dim = OUTPUTS[config.output]

    def sample(self, num_systems: int, *, generator: torch.Generator) -> RLCParams:
        cfg, B, m = self.config, num_systems, self.output_dim
        R = log_uniform((B,), cfg.bounds("resistance"), generator)
        L = log_uniform((B,), cfg.bounds("inductance"), generator)
        C = log_uniform((B,), cfg.bounds("capacitance"), generator)
        A_c, b = continuous_model(R, L, C)
        A, Bd = zoh(A_c, b, cfg.dt)
        Q = van_loan(A_c, b, cfg.dt) * (cfg.disturbance_std**2 * cfg.dt)
        out = torch.zeros(B, 2, 2, dtype=torch.float64, device=R.device)
        out[:, 0, 0], out[:, 1, 1] = 1.0, R  # y = (v_C, R i_L)
        P0 = torch.diag_embed(torch.stack([torch.ones_like(R), C / L], -1)) * cfg.initial_voltage_std**2
        eye = torch.eye(m, dtype=torch.float64, device=R.device)
        return RLCParams(
            resistance=R,
            inductance=L,
            capacitance=C,
            A=A,
            B=Bd,
            C=out[:, :m],
            Q=Q,
            R=(cfg.output_std**2 * eye).expand(B, m, m).clone(),
            P0=P0,
            x0_mean=torch.zeros(B, 2, dtype=torch.float64, device=R.device),
        )

    def simulate(self, params: RLCParams, horizon: int, *, generator: torch.Generator) -> Trajectories:
        cfg, m, p = self.config, self.output_dim, params
        A, Bd, C = (M.to(self.dtype) for M in (p.A, p.B, p.C))
        num = A.shape[0]
        w_root = psd_sqrt(p.Q).to(self.dtype)  # (B, 2, 2), w_root w_root^T = Q
        p0_root = p.P0.sqrt().to(self.dtype)  # P0 is diagonal
        x0 = p.x0_mean.to(self.dtype) + (p0_root @ normal((num, 2, 1), generator, self.dtype))[..., 0]
        u = normal((num, horizon + 1, 1), generator, self.dtype) * cfg.input_std  # (B, T+1, 1)
        w = normal((num, horizon + 1, 2), generator, self.dtype) @ w_root.mT  # (B, T+1, 2), w_T unused
        v = normal((num, horizon + 1, m), generator, self.dtype) * cfg.output_std
        x, y = simulate_linear(A, C, x0, w + u @ Bd.mT, v)  # the source enters as the known forcing B u_t
        return Trajectories(y=y, u=u, x=x, params=params, family=self.name)

    @staticmethod
    def state_space(params: RLCParams) -> StateSpace:
        """x_{t+1} = A x_t + B u_t + w_t, y_t = C x_t + v_t, x_0 ~ N(x0_mean, P0)."""
        p = params
        return linear_state_space(p.A, p.C, p.Q, p.R, p.P0, B=p.B, m0=p.x0_mean)
