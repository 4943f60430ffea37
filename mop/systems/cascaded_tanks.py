"""Two water tanks in cascade with square-root outflows and overflow, the family "cascaded-tanks": the plant
of the cascaded-tanks nonlinear system-identification benchmark (Schoukens, Mattsson, Wigren and Noel 2016;
Relan et al. 2017), written from its physics with random parameters per system.

A pump driven by the voltage u (V) fills the upper tank; water drains through an opening at the bottom of
each tank (Torricelli: outflow a_i sqrt(h_i)), from the upper into the lower tank and from the lower into
the reservoir. Levels h_i are in the sensors' units (V, 0..10 as in the benchmark's records), time in s:

    A1 dh1/dt = k_p u - a1 sqrt(h1)                     (+ overflow: h1 <= H, the excess spills)
    A2 dh2/dt = a1 sqrt(h1) - a2 sqrt(h2) + rho spill   (h2 <= H, its excess leaves the plant)
    y_t = h2(t Ts) + v_t,   v_t ~ N(0, sigma_v^2),   state x = (h1, h2),   Ts = 4 s (the benchmark's).
    With system.sensor_saturation = s > 0 the level sensor saturates below the rim: y_t = min(h2 + v_t, S),
    S = H (1 - U(0, s)) per system, flat and noise-free at S as the benchmark's records are at 10 V.

Discretised by SUBSTEPS = 2 classical Runge-Kutta (RK4) steps of dt = Ts / 2 = 2 s per sample, u held
over the sample; after each substep the levels are clipped to [0, H], the upper tank's excess volume
A1 (h1 - H) spills and the fraction rho of it reaches the lower tank. Then x_{t+1} = clip(f(x_t, u_t) + w_t),
w_t ~ N(0, q^2 I) (process_noise_std). Measured against scipy's solve_ivp (rtol 1e-10) without overflow:
within 1e-5 V over 300 samples (tests/test_cascaded_tanks.py).
The equilibrium for a constant u without overflow: h1 = (k_p u / a1)^2, h2 = (k_p u / a2)^2.

Random per system (U = uniform), chosen so the benchmark's scales appear (levels O(1..10) V, inputs 0..10 V)
with local time constants 2 A_i sqrt(h_i) / a_i of about 10 to 35 samples (5th to 95th percentile):
    areas A1, A2 ~ U(0.75, 1.5) (relative cross-sections), outflow coefficients a1, a2 ~ U(0.04, 0.07),
    pump gain k_p ~ U(0.025, 0.04), maximum level H ~ U(8, 10), overflow fraction rho ~ U(0.25, 0.75),
    operating level h_op ~ U(2, 8): the operating voltage u_op = min(a1, a2) sqrt(h_op) / k_p puts the
    fuller tank's equilibrium at h_op (u_op 1.4..7.9 V), so swings of the input sometimes overflow it,
    input swing: relative RMS U(0.25, 1) input_amplitude, sigma_v ~ U(0.2, 1) noise_std.
Input u_t = clip(u_op (1 + amplitude s_t), 0, 10) with s_t of unit RMS: "multisine" (random phases, equal
amplitudes on the lines k / (T + 1) up to U(0.5, 1) bandwidth cycles per sample; the benchmark's band
0..0.0144 Hz is 0.058 at Ts = 4 s), "white" (N(0, 1) i.i.d.) or "prbs" (+-1, switching with probability
bandwidth per step). x_0 ~ N(m0, P0) clipped, m0 the equilibrium at u_op (clipped), P0 = (x0_spread m0)^2
per tank ("random"), or x_0 = m0 ("steady": P0 = 1e-8 I).

Where this differs from the real benchmark: there one plant gives both records (here every system is drawn
anew); the pump's flow is taken linear in u and the sensor linear in the level (the real characteristics are
not published with the data); the share rho of the overflow reaching the lower tank is unknown there; the
noise here is white and Gaussian; its sensor reads every level unless system.sensor_saturation is set (the
real records sit exactly at 10 V for 4.6% of the estimation record and 3.6% of the test); its records are
1024 samples of one multisine design (estimation and validation realisations), ours have the record's
length and a per-system band and amplitude.

The filters (EKF, UKF, particle filter) are given f, its Jacobian (chained through the RK4 stages;
d sqrt(h)/dh uses h >= 1e-3 so it stays finite at an empty tank, the clip's derivative is 1 inside (0, H) and
0 outside), C = [0, 1], Q = max(q^2, 1e-8) I, R = sigma_v^2 (+ 1e-8), (m0, P0) and the clip to [0, H] as the
state projection. They are not given the sensor's saturation (their output is linear): where it bites
(system.sensor_saturation > 0, an output at S) they are misspecified.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
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
    uniform,
)

TS, SUBSTEPS, U_MAX = 4.0, 2, 10.0
SQRT_FLOOR, JITTER = 1e-3, 1e-8
RANGES = {
    "area1": (0.75, 1.5),
    "area2": (0.75, 1.5),
    "outflow1": (0.04, 0.07),
    "outflow2": (0.04, 0.07),
    "pump": (0.025, 0.04),
    "max_level": (8.0, 10.0),
    "overflow_to_lower": (0.25, 0.75),
}
OPERATING_LEVEL = (2.0, 8.0)
INPUTS = ("multisine", "white", "prbs")
PHYSICS = tuple(RANGES)  # the parameters tank_step reads


Levels = tuple[Tensor, Tensor]  # (h1, h2), each (...): kept apart inside the substeps (no stacking)


def _rhs(h: Levels, u: Tensor, p: dict[str, Tensor]) -> Levels:
    """(dh1/dt, dh2/dt) at the levels h under u (...). A full upper tank (h1 >= H) holds no more: the net
    inflow spills, rho of it into the lower tank; a full lower tank loses what it cannot hold."""
    H = p["max_level"]
    q1 = p["outflow1"] * torch.minimum(h[0].clamp(min=0), H).sqrt()
    q2 = p["outflow2"] * torch.minimum(h[1].clamp(min=0), H).sqrt()
    net = p["pump"] * u - q1
    spill = torch.where(h[0] >= H, net.clamp(min=0), torch.zeros_like(net))
    dh2 = (q1 + p["overflow_to_lower"] * spill - q2) / p["area2"]
    return (net - spill) / p["area1"], torch.where(h[1] >= H, dh2.clamp(max=0), dh2)


def _rhs_jacobian(h: Levels, u: Tensor, p: dict[str, Tensor]) -> Tensor:
    """d(dh/dt)/dh (..., 2, 2) of _rhs, with d sqrt(h)/dh taken at max(h, SQRT_FLOOR) (finite at an empty
    tank); a tank at or above its rim has d q / d h = 0, and a full lower tank that is filling a zero row."""
    H = p["max_level"]
    d1 = p["outflow1"] / (2 * h[0].clamp(min=SQRT_FLOOR).sqrt()) * (h[0] < H)  # d q1 / d h1
    d2 = p["outflow2"] / (2 * h[1].clamp(min=SQRT_FLOOR).sqrt()) * (h[1] < H)
    filling = (h[1] >= H) & (_rhs(h, u, p)[1] == 0)  # dh2/dt clipped to 0 at the rim
    row1 = torch.stack([-d1 / p["area1"], torch.zeros_like(d1)], dim=-1)
    row2 = torch.stack([d1 / p["area2"], -d2 / p["area2"]], dim=-1) * ~filling[..., None]
    return torch.stack([row1, row2], dim=-2)


def _substep(h: Levels, u: Tensor, p: dict[str, Tensor], J: Tensor | None) -> tuple[Levels, Tensor | None]:
    """One RK4 step of dt = TS / SUBSTEPS, then the rims: h, u (...) -> (h', J' = dh'/dh J (..., 2, 2));
    J None skips the Jacobian. The upper tank's excess volume A1 (z1 - H) spills, rho of it into the lower."""
    dt, H = TS / SUBSTEPS, p["max_level"]
    points, slopes = [h], [_rhs(h, u, p)]
    for c in (dt / 2, dt / 2, dt):  # the RK4 stages
        points.append((h[0] + c * slopes[-1][0], h[1] + c * slopes[-1][1]))
        slopes.append(_rhs(points[-1], u, p))
    z1, z2 = (
        h[i] + dt / 6 * (slopes[0][i] + 2 * slopes[1][i] + 2 * slopes[2][i] + slopes[3][i]) for i in (0, 1)
    )
    spill = (z1 - H).clamp(min=0) * p["area1"]
    z2 = z2 + p["overflow_to_lower"] * spill / p["area2"]
    h_next = (torch.minimum(z1.clamp(min=0), H), torch.minimum(z2.clamp(min=0), H))
    if J is None:
        return h_next, None
    eye = torch.eye(2, dtype=z1.dtype, device=z1.device)
    dk = [_rhs_jacobian(points[0], u, p)]  # d slope_i / dh by the chain rule through the stages
    for point, c in zip(points[1:], (dt / 2, dt / 2, dt), strict=True):
        dk.append(_rhs_jacobian(point, u, p) @ (eye + c * dk[-1]))
    dz = eye + dt / 6 * (dk[0] + 2 * dk[1] + 2 * dk[2] + dk[3])  # (..., 2, 2), before the rims
    over = (z1 > H).to(z1.dtype)  # z2 above already holds the spill
    dz2 = dz[..., 1, :] + (p["overflow_to_lower"] * over * p["area1"] / p["area2"])[..., None] * dz[..., 0, :]
    in1 = ((z1 > 0) & (z1 < H)).to(z1.dtype)[..., None]  # the clip's derivative
    in2 = ((z2 > 0) & (z2 < H)).to(z1.dtype)[..., None]
    return h_next, torch.stack([in1 * dz[..., 0, :], in2 * dz2], dim=-2) @ J


def tank_step(x: Tensor, u: Tensor, p: dict[str, Tensor]) -> Tensor:
    """x_next = f(x, u): x (..., 2) levels, u (..., 1) volts, p[name] broadcastable to (...). No noise."""
    h = x.unbind(-1)
    for _ in range(SUBSTEPS):
        h, _ = _substep(h, u[..., 0], p, None)
    return torch.stack(h, dim=-1)


def tank_jacobian(x: Tensor, u: Tensor, p: dict[str, Tensor]) -> Tensor:
    """df/dx (..., 2, 2) at x (..., 2), u (..., 1): the product of the substeps' Jacobians, with
    d sqrt(h)/dh at max(h, SQRT_FLOOR) and the clip's derivative 1 inside (0, H), 0 outside."""
    h, J = x.unbind(-1), torch.eye(2, dtype=x.dtype, device=x.device).expand(*x.shape[:-1], 2, 2)
    for _ in range(SUBSTEPS):
        h, J = _substep(h, u[..., 0], p, J)
    return J


def equilibrium(u: Tensor, p: dict[str, Tensor]) -> Tensor:
    """(..., 2) levels at rest under a constant u (...): h1 = (k_p u / a1)^2, h2 = (k_p u / a2)^2 without
    overflow; an overflowing upper tank stays at H and passes a1 sqrt(H) + rho (k_p u - a1 sqrt(H))."""
    H, inflow = p["max_level"], p["pump"] * u
    h1 = torch.minimum((inflow / p["outflow1"]) ** 2, H)
    through = torch.where(inflow > p["outflow1"] * H.sqrt(), p["outflow1"] * H.sqrt(), inflow)
    into_lower = through + p["overflow_to_lower"] * (inflow - through)
    return torch.stack([h1, torch.minimum((into_lower / p["outflow2"]) ** 2, H)], dim=-1)


def clip_levels(x: Tensor, max_level: Tensor) -> Tensor:
    """x (B, ..., 2) clipped to [0, H] with H (B,): the tanks' rims, the state projection."""
    H = max_level.reshape(-1, *([1] * (x.dim() - 1)))
    return torch.minimum(x.clamp(min=0), H)


def unit_rms_signal(kind: str, p: dict[str, Tensor], steps: int, generator: torch.Generator) -> Tensor:
    """(B, steps) excitation of unit RMS: a random-phase multisine on lines k / steps, k = 1..K_b with
    K_b = floor(bandwidth_b steps) kept in [1, (steps - 1) / 2]; i.i.d. N(0, 1) ("white"); or a +-1
    telegraph switching with probability bandwidth_b per step ("prbs")."""
    B, band = p["bandwidth"].shape[0], p["bandwidth"]
    if kind == "white":
        return normal((B, steps), generator)
    if kind == "prbs":
        flips = uniform((B, steps), 0, 1, generator) < band[:, None]
        start = torch.where(uniform((B, 1), 0, 1, generator) < 0.5, -1.0, 1.0).double()
        return start * (1 - 2 * (flips.long().cumsum(1) % 2)).double()
    lines = max(1, (steps - 1) // 2)  # below Nyquist
    K = (band * steps).floor().clamp(1, lines)  # (B,) lines in use
    phase = uniform((B, lines), 0, 2 * math.pi, generator)
    on = torch.arange(1, lines + 1, dtype=torch.float64, device=K.device)[None] <= K[:, None]  # (B, L)
    spectrum = torch.zeros(B, steps // 2 + 1, dtype=torch.complex128, device=K.device)
    spectrum[:, 1 : lines + 1] = on * torch.polar(torch.full_like(phase, steps / 2), phase)
    waves = torch.fft.irfft(spectrum, n=steps)  # sum_k cos(2 pi k t / steps + phase_k), (B, steps)
    return waves / (K[:, None] / 2).sqrt()


@dataclass(frozen=True)
class CascadedTanksConfig(SystemConfig):
    """input: "multisine", "white" or "prbs"; input_amplitude: largest relative RMS of the input's swing about
    u_op (per system U(0.25, 1) times it); bandwidth: largest multisine frequency (cycles per sample) or
    prbs switching probability; noise_std: largest measurement-noise std (V, per system U(0.2, 1) times
    it); process_noise_std: std of w_t per tank (V per sample); x0: "random" or "steady"; x0_spread: the
    relative std of x_0 about the equilibrium ("random"); sensor_saturation: the largest share of the tank's
    height above the level sensor's top (per system U(0, sensor_saturation) of H; 0: the sensor reads every
    level)."""

    family: str = "cascaded-tanks"
    input: str = "multisine"
    input_amplitude: float = 0.4
    bandwidth: float = 0.05
    noise_std: float = 0.05
    process_noise_std: float = 0.01
    x0: str = "random"
    x0_spread: float = 0.3
    sensor_saturation: float = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        check(self.input in INPUTS, f"system.input must be one of {', '.join(INPUTS)}, got {self.input!r}")
        check(
            0 < self.input_amplitude <= 2,
            f"system.input_amplitude must be in (0, 2], got {self.input_amplitude}",
        )
        check(0 < self.bandwidth <= 0.5, f"system.bandwidth must be in (0, 0.5], got {self.bandwidth}")
        check(self.noise_std >= 0, f"system.noise_std must be >= 0, got {self.noise_std}")
        check(
            self.process_noise_std >= 0,
            f"system.process_noise_std must be >= 0, got {self.process_noise_std}",
        )
        check(self.x0 in ("random", "steady"), f"system.x0 must be 'random' or 'steady', got {self.x0!r}")
        check(0 <= self.x0_spread <= 1, f"system.x0_spread must be in [0, 1], got {self.x0_spread}")
        check(
            0 <= self.sensor_saturation < 1,
            f"system.sensor_saturation must be in [0, 1), got {self.sensor_saturation}",
        )


@dataclass(frozen=True)
class CascadedTanksParams(SystemParams):
    """The physics (PHYSICS: area1, area2, outflow1, outflow2, pump, max_level, overflow_to_lower, each (B,));
    the input's operating point u_op, amplitude and bandwidth (B,); noise_std (B,); sensor_top S (B,) (inf:
    no saturation); C (B, 1, 2); Q (B, 2, 2);
    R (B, 1, 1); x0_mean (B, 2); P0 (B, 2, 2). The tanks' helpers (tank_step, ...) take the physics as a dict
    (params.as_dict())."""

    area1: Tensor
    area2: Tensor
    outflow1: Tensor
    outflow2: Tensor
    pump: Tensor
    max_level: Tensor
    overflow_to_lower: Tensor
    u_op: Tensor
    amplitude: Tensor
    bandwidth: Tensor
    noise_std: Tensor
    sensor_top: Tensor
    C: Tensor
    Q: Tensor
    R: Tensor
    x0_mean: Tensor
    P0: Tensor


@register_family("cascaded-tanks", CascadedTanksConfig)
class CascadedTanksFamily(SystemFamily):
    """params: CascadedTanksParams. Trajectories carry u (B, T+1, 1) in volts (u_T is drawn too but moves
    nothing) and the levels x (B, T+1, 2)."""

    Params = CascadedTanksParams
    state_dim, output_dim, input_dim = 2, 1, 1

    def sample(self, num_systems: int, *, generator: torch.Generator) -> CascadedTanksParams:
        B, cfg = num_systems, self.config
        p = {name: uniform((B,), *bounds, generator) for name, bounds in RANGES.items()}
        level = uniform((B,), *OPERATING_LEVEL, generator)
        p["u_op"] = torch.minimum(p["outflow1"], p["outflow2"]) * level.sqrt() / p["pump"]
        p["amplitude"] = uniform((B,), 0.25, 1.0, generator) * cfg.input_amplitude
        p["bandwidth"] = uniform((B,), 0.5, 1.0, generator) * cfg.bandwidth
        p["noise_std"] = uniform((B,), 0.2, 1.0, generator) * cfg.noise_std
        m0 = equilibrium(p["u_op"], p)
        spread = cfg.x0_spread if cfg.x0 == "random" else 0.0
        eye = torch.eye(2, dtype=torch.float64, device=m0.device)
        p["C"] = eye[None, 1:].expand(B, 1, 2).clone()
        p["Q"] = max(cfg.process_noise_std**2, JITTER) * eye.expand(B, 2, 2).clone()
        p["R"] = (p["noise_std"] ** 2 + JITTER)[:, None, None]
        p["x0_mean"], p["P0"] = m0, torch.diag_embed((spread * m0) ** 2 + JITTER)
        p["sensor_top"] = torch.full_like(m0[:, 0], math.inf)
        if cfg.sensor_saturation > 0:  # drawn last: the other draws stay those of a family without it
            p["sensor_top"] = p["max_level"] * (1 - uniform((B,), 0, cfg.sensor_saturation, generator))
        return CascadedTanksParams(**p)

    def simulate(
        self, params: CascadedTanksParams, horizon: int, *, generator: torch.Generator
    ) -> Trajectories:
        p, cfg = params.map(Tensor.double).as_dict(), self.config
        B = p["u_op"].shape[0]
        s = unit_rms_signal(cfg.input, p, horizon + 1, generator)  # (B, T+1)
        u = (p["u_op"][:, None] * (1 + p["amplitude"][:, None] * s)).clamp(0, U_MAX)[..., None]
        w = normal((B, horizon, 2), generator) * cfg.process_noise_std
        v = normal((B, horizon + 1, 1), generator) * p["noise_std"][:, None, None]
        spread = (cfg.x0_spread if cfg.x0 == "random" else 0.0) * p["x0_mean"]
        x0 = clip_levels(p["x0_mean"] + spread * normal((B, 2), generator), p["max_level"])
        x = simulate_levels(x0, u, p, w)  # (B, T+1, 2)
        y = x[..., 1:] + v
        if cfg.sensor_saturation > 0:
            y = torch.minimum(y, p["sensor_top"][:, None, None])
        return Trajectories(
            y=y.to(self.dtype),
            u=u.to(self.dtype),
            x=x.to(self.dtype),
            params=params,
            family=self.name,
        )

    @staticmethod
    def state_space(params: CascadedTanksParams) -> StateSpace:
        """f and its Jacobian with the physics known, C = [0, 1], Q, R, N(x0_mean, P0), the clip to [0, H]."""
        p = params.map(Tensor.double).as_dict()
        per_point = {k: p[k][:, None] for k in PHYSICS}  # (B, 1): broadcast over point sets (B, N)
        return StateSpace(
            f=lambda x, u, t: tank_step(x, u, per_point),
            C=p["C"],
            Q=p["Q"],
            R=p["R"],
            m0=p["x0_mean"],
            P0=p["P0"],
            jacobian=lambda x, u, t: tank_jacobian(x, u, {k: p[k] for k in PHYSICS}),
            project=lambda x: clip_levels(x, p["max_level"]),
        )


def simulate_levels(x0: Tensor, u: Tensor, p: dict[str, Tensor], w: Tensor | None = None) -> Tensor:
    """Levels (B, T+1, 2) from x0 (B, 2) under u (B, T+1, 1): x_{t+1} = clip(f(x_t, u_t) + w_t) with w
    (B, T, 2), or f(x_t, u_t) alone (w None); p[name] (B,).

    Runs tank_step's arithmetic in numpy, operation for operation in float64 (_substep_numpy): on the
    training batches (16 systems) torch's per-operation overhead made this loop half of a class model's
    training step (0.49 of 1.04 s at 500 steps; numpy 3.8x faster). tests/test_cascaded_tanks.py checks it
    against a loop of tank_step (the filters' f): equal to float rounding (the largest difference seen,
    1.8e-15 V, is one unit in the last place of torch's kernels). The result has x0's dtype and device."""
    phys = {k: p[k].detach().double().cpu().numpy() for k in PHYSICS}
    un = u.detach().double().cpu().numpy()[..., 0]  # (B, T+1)
    wn = None if w is None else w.detach().double().cpu().numpy()
    H = phys["max_level"]
    out = np.empty((*un.shape, 2))
    out[:, 0] = x0.detach().double().cpu().numpy()
    for t in range(un.shape[1] - 1):
        h = (out[:, t, 0], out[:, t, 1])
        for _ in range(SUBSTEPS):
            h = _substep_numpy(h, un[:, t], phys)
        for i in (0, 1):
            out[:, t + 1, i] = h[i] if wn is None else np.minimum(np.maximum(h[i] + wn[:, t, i], 0.0), H)
    return torch.from_numpy(out).to(device=x0.device, dtype=x0.dtype)


def _rhs_numpy(h: tuple[np.ndarray, np.ndarray], u: np.ndarray, p: dict[str, np.ndarray]):
    """_rhs in numpy (the same operations in the same order)."""
    H = p["max_level"]
    q1 = p["outflow1"] * np.sqrt(np.minimum(np.maximum(h[0], 0.0), H))
    q2 = p["outflow2"] * np.sqrt(np.minimum(np.maximum(h[1], 0.0), H))
    net = p["pump"] * u - q1
    spill = np.where(h[0] >= H, np.maximum(net, 0.0), 0.0)
    dh2 = (q1 + p["overflow_to_lower"] * spill - q2) / p["area2"]
    return (net - spill) / p["area1"], np.where(h[1] >= H, np.minimum(dh2, 0.0), dh2)


def _substep_numpy(h: tuple[np.ndarray, np.ndarray], u: np.ndarray, p: dict[str, np.ndarray]):
    """_substep without the Jacobian, in numpy (the same operations in the same order)."""
    dt, H = TS / SUBSTEPS, p["max_level"]
    slopes = [_rhs_numpy(h, u, p)]
    for c in (dt / 2, dt / 2, dt):  # the RK4 stages
        slopes.append(_rhs_numpy((h[0] + c * slopes[-1][0], h[1] + c * slopes[-1][1]), u, p))
    z1, z2 = (
        h[i] + dt / 6 * (slopes[0][i] + 2 * slopes[1][i] + 2 * slopes[2][i] + slopes[3][i]) for i in (0, 1)
    )
    spill = np.maximum(z1 - H, 0.0) * p["area1"]
    z2 = z2 + p["overflow_to_lower"] * spill / p["area2"]
    return np.minimum(np.maximum(z1, 0.0), H), np.minimum(np.maximum(z2, 0.0), H)


__all__ = [
    "CascadedTanksConfig",
    "CascadedTanksFamily",
    "CascadedTanksParams",
    "RANGES",
    "SUBSTEPS",
    "TS",
    "equilibrium",
    "simulate_levels",
    "tank_jacobian",
    "tank_step",
]
