"""Lightly damped oscillators with polynomial stiffness, the family "duffing": the class of the Silverbox
benchmark (an electronic Duffing oscillator: a mass, a damper and a spring whose force is a polynomial of the
displacement, driven by a force), with random parameters per system, so that a class model trained on it
identifies a new member in context.

Time is in samples (the sampling time Ts = 1); the displacement y and the force u are in units where the
system's linear part (its stiffness polynomial without the quadratic and cubic terms) answers the record's
input with an RMS of 1:

    dy/dt = v,   dv/dt = -2 zeta omega v - omega^2 (y + k2 y^2 + k3 y^3) + b u(t),   u held over the sample,
    y_t = y(t) + e_t,   e_t ~ N(0, sigma^2),   state x = (y, v),   x_0 = 0 (at rest).

Discretised by SUBSTEPS = 8 classical Runge-Kutta (RK4) steps per sample: one sample from the same state is
within 3e-5 of scipy's solve_ivp (rtol 1e-10) on the stiffest springs drawn, against the linear response's
RMS of 1 (tests/test_duffing.py); with k2 = k3 = 0 it is the exact zero-order-hold discretisation (expm)
to 1.5e-6.

Random per system (U = uniform; log-U uniform in the logarithm), chosen to span the Silverbox's measured
linear part (an ARX(2, 2) fit of its estimation record: omega = 0.71 rad / sample, zeta = 0.044):
    natural frequency omega ~ U(omega_low, omega_high) rad / sample (default 0.2..1.2),
    damping ratio zeta ~ log-U(zeta_low, zeta_high) (default 0.01..0.15),
    cubic stiffness k3 ~ U(0, cubic) (hardening, default 1: at the linear RMS the spring is up to twice as
    stiff), quadratic stiffness k2 ~ U(-quadratic, quadratic) (an asymmetric spring, default 0.2),
    b: set per system and record so that the linear part's response to the drawn input has RMS 1 (one
    extra linear simulation), noise sigma ~ U(0, noise_std) (default 0.01, relative to that RMS).
Input u (unit RMS before b): "multisine" (random phases, equal amplitudes on the lines up to U(0.5, 1)
bandwidth cycles per sample: the Silverbox's records are odd multisines up to 200 Hz at 610 Hz, 0.33),
"white" (N(0, 1) i.i.d.), "arrow" (white noise whose amplitude grows linearly from 0 to sqrt(3), the
Silverbox's test "arrow" shape) or "mixed" (each system draws "multisine" or "white"). "mixed" leaves the
arrow out: a record that starts at rest with no excitation fixes a record-normalised model's feature frame
(mop.models.features.feature_frame, from its first steps) at a tiny scale, and the cubed regressors then
blow up as the amplitude grows (the class model's one-step RMSE over t >= 50 was 5844 on 500 test systems
with arrows among them).

Where this differs from the real Silverbox: there the stiffness polynomial, the damping and the input's
path through an amplifier are one fixed plant and the noise is not white; the class holds no friction or
hysteresis. The filters (EKF, UKF, particle filter) are given f (the RK4 map, in torch), C = [1, 0],
Q = JITTER I, R = sigma^2 + JITTER and x_0 ~ N(0, JITTER I); the EKF's Jacobian is autograd's.
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
from mop.systems.cascaded_tanks import unit_rms_signal

SUBSTEPS, JITTER = 8, 1e-8
INPUTS = ("multisine", "white", "arrow", "mixed")
KINDS = INPUTS[:3]  # the signals by index (DuffingParams.kind)
MIXED = 2  # "mixed" draws KINDS[0] or KINDS[1] per system


@dataclass(frozen=True)
class DuffingConfig(SystemConfig):
    """omega_low, omega_high: the natural frequency's range (rad / sample, below pi / 2); zeta_low, zeta_high:
    the damping ratio's (log-uniform); cubic: the largest cubic stiffness k3 (k3 ~ U(0, cubic)); quadratic:
    the largest |k2|; input: "multisine", "white", "arrow" or "mixed"; bandwidth: the multisine's largest
    frequency (cycles per sample); noise_std: the largest measurement-noise std (relative to the linear
    response's RMS of 1)."""

    family: str = "duffing"
    omega_low: float = 0.2
    omega_high: float = 1.2
    zeta_low: float = 0.01
    zeta_high: float = 0.15
    cubic: float = 1.0
    quadratic: float = 0.2
    input: str = "mixed"
    bandwidth: float = 0.45
    noise_std: float = 0.01

    def __post_init__(self) -> None:
        super().__post_init__()
        check(
            0 < self.omega_low <= self.omega_high < math.pi / 2,
            f"system.omega_low <= omega_high must lie in (0, pi / 2), got {self.omega_low}, "
            f"{self.omega_high}",
        )
        check(
            0 < self.zeta_low <= self.zeta_high < 1,
            f"system.zeta_low <= zeta_high must lie in (0, 1), got {self.zeta_low}, {self.zeta_high}",
        )
        check(self.cubic >= 0, f"system.cubic must be >= 0 (a hardening spring), got {self.cubic}")
        check(self.quadratic >= 0, f"system.quadratic must be >= 0 (k2 ~ U(-it, it)), got {self.quadratic}")
        check(self.input in INPUTS, f"system.input must be one of {', '.join(INPUTS)}, got {self.input!r}")
        check(0 < self.bandwidth <= 0.5, f"system.bandwidth must be in (0, 0.5], got {self.bandwidth}")
        check(self.noise_std >= 0, f"system.noise_std must be >= 0, got {self.noise_std}")


@dataclass(frozen=True)
class DuffingParams(SystemParams):
    """omega, zeta, k2, k3 (B,): the oscillator; bandwidth (B,): the multisine's band; kind (B,): the input's
    index in KINDS; noise_std (B,); gain (B,): b, set by simulate (NaN after sample, before it); C (B, 1, 2);
    Q (B, 2, 2); R (B, 1, 1); x0_mean (B, 2); P0 (B, 2, 2)."""

    omega: Tensor
    zeta: Tensor
    k2: Tensor
    k3: Tensor
    bandwidth: Tensor
    kind: Tensor
    noise_std: Tensor
    gain: Tensor
    C: Tensor
    Q: Tensor
    R: Tensor
    x0_mean: Tensor
    P0: Tensor


def _rhs(y, v, u, p):
    """(dy/dt, dv/dt) for arrays or tensors of the same shape; p holds omega, zeta, k2, k3, gain."""
    w2 = p["omega"] ** 2
    spring = y + p["k2"] * y * y + p["k3"] * y * y * y
    return v, -2 * p["zeta"] * p["omega"] * v - w2 * spring + p["gain"] * u


def oscillator_step(y, v, u, p):
    """One sample: SUBSTEPS RK4 steps of 1 / SUBSTEPS with u held; numpy arrays or torch tensors."""
    h = 1.0 / SUBSTEPS
    for _ in range(SUBSTEPS):
        k1 = _rhs(y, v, u, p)
        k2 = _rhs(y + h / 2 * k1[0], v + h / 2 * k1[1], u, p)
        k3 = _rhs(y + h / 2 * k2[0], v + h / 2 * k2[1], u, p)
        k4 = _rhs(y + h * k3[0], v + h * k3[1], u, p)
        y = y + h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        v = v + h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
    return y, v


def simulate_states(u: np.ndarray, p: dict[str, np.ndarray]) -> np.ndarray:
    """States (B, T+1, 2) from rest under u (B, T+1) (u_T moves nothing); p[name] (B,) float64 arrays."""
    B, L = u.shape
    out = np.zeros((B, L, 2))
    y, v = np.zeros(B), np.zeros(B)
    for t in range(L - 1):
        y, v = oscillator_step(y, v, u[:, t], p)
        out[:, t + 1, 0], out[:, t + 1, 1] = y, v
    return out


def input_signal(kind: Tensor, p: dict[str, Tensor], steps: int, generator: torch.Generator) -> Tensor:
    """(B, steps) unit-RMS excitation: per system the KINDS[kind] signal (all three are drawn, so a system's
    signal does not depend on the others' kinds)."""
    multisine = unit_rms_signal("multisine", {"bandwidth": p["bandwidth"]}, steps, generator)
    white = normal(multisine.shape, generator)
    ramp = torch.linspace(0, math.sqrt(3), steps, dtype=torch.float64, device=white.device)
    arrow = normal(multisine.shape, generator) * ramp[None]
    signals = torch.stack([multisine, white, arrow])  # (3, B, steps)
    return signals.gather(0, kind[None, :, None].long().expand(1, -1, steps))[0]


@register_family("duffing", DuffingConfig)
class DuffingFamily(SystemFamily):
    """params: DuffingParams. Trajectories carry u (B, T+1, 1), y (B, T+1, 1) and x = (y, v) (B, T+1, 2)."""

    Params = DuffingParams
    state_dim, output_dim, input_dim = 2, 1, 1

    def sample(self, num_systems: int, *, generator: torch.Generator) -> DuffingParams:
        B, cfg = num_systems, self.config
        log_zeta = uniform((B,), math.log(cfg.zeta_low), math.log(cfg.zeta_high), generator)
        kind = (
            torch.full((B,), KINDS.index(cfg.input), dtype=torch.float64, device=log_zeta.device)
            if cfg.input != "mixed"
            else uniform((B,), 0, MIXED, generator).floor().clamp(max=MIXED - 1)
        )
        p = {
            "omega": uniform((B,), cfg.omega_low, cfg.omega_high, generator),
            "zeta": log_zeta.exp(),
            "k2": uniform((B,), -cfg.quadratic, cfg.quadratic, generator),
            "k3": uniform((B,), 0.0, cfg.cubic, generator),
            "bandwidth": uniform((B,), 0.5, 1.0, generator) * cfg.bandwidth,
            "kind": kind,
            "noise_std": uniform((B,), 0.0, 1.0, generator) * cfg.noise_std,
        }
        p["gain"] = torch.full_like(p["omega"], float("nan"))
        eye = torch.eye(2, dtype=torch.float64, device=kind.device)
        p["C"] = eye[None, :1].expand(B, 1, 2).clone()
        p["Q"] = JITTER * eye.expand(B, 2, 2).clone()
        p["R"] = (p["noise_std"] ** 2 + JITTER)[:, None, None]
        p["x0_mean"] = torch.zeros(B, 2, dtype=torch.float64, device=kind.device)
        p["P0"] = JITTER * eye.expand(B, 2, 2).clone()
        return DuffingParams(**p)

    def simulate(self, params: DuffingParams, horizon: int, *, generator: torch.Generator) -> Trajectories:
        p = params.map(Tensor.double).as_dict()
        u = input_signal(p["kind"], p, horizon + 1, generator)  # (B, T+1)
        e = normal((u.shape[0], horizon + 1, 1), generator) * p["noise_std"][:, None, None]
        phys = {k: p[k].cpu().numpy() for k in ("omega", "zeta", "k2", "k3")}
        un = u.cpu().numpy()
        linear = simulate_states(un, {**phys, "k2": 0 * phys["k2"], "k3": 0 * phys["k3"], "gain": 1.0})
        rms = np.sqrt(np.mean(linear[:, :, 0] ** 2, axis=1))
        gain = 1.0 / np.where(rms > 0, rms, 1.0)
        x = torch.from_numpy(simulate_states(un, {**phys, "gain": gain})).to(u.device)
        params = DuffingParams(**{**params.as_dict(), "gain": torch.from_numpy(gain).to(params.omega)})
        return Trajectories(
            y=(x[..., :1] + e).to(self.dtype),
            u=u[..., None].to(self.dtype),
            x=x.to(self.dtype),
            params=params,
            family=self.name,
        )

    @staticmethod
    def state_space(params: DuffingParams) -> StateSpace:
        """f (the RK4 map) with the oscillator known, C = [1, 0], Q = JITTER I, R, x_0 ~ N(0, JITTER I)."""
        p = params.map(Tensor.double).as_dict()
        per_point = {k: p[k][:, None] for k in ("omega", "zeta", "k2", "k3", "gain")}  # (B, 1)

        def f(x: Tensor, u: Tensor | None, t: int) -> Tensor:
            y, v = oscillator_step(x[..., 0], x[..., 1], u[..., 0], per_point)
            return torch.stack([y, v], dim=-1)

        return StateSpace(f=f, C=p["C"], Q=p["Q"], R=p["R"], m0=p["x0_mean"], P0=p["P0"])


__all__ = [
    "DuffingConfig",
    "DuffingFamily",
    "DuffingParams",
    "SUBSTEPS",
    "oscillator_step",
    "simulate_states",
]
