"""Random SISO LTI systems driven by white noise, the family "lti-siso": the in-context system-identification
class of Forgione, Pura and Piga ("From system models to class models", 2023; github
forgi86/sysid-transformers, their `drss_matrices` and `LinearDynamicalDatasetNb`), re-implemented batched:

    x_{t+1} = A x_t + B u_t,   y_t = C x_t (strictly proper),   x_0 = 0,   u_t ~ N(0, 1) i.i.d.,
    y normalized per trajectory: (y - mean_t y) / (std_t y + 1e-6) over all T + 1 outputs,
    then (our option, theirs at test time) + noise_std * N(0, 1) on the normalized outputs.

System order n ~ U{1..max_order} (10). Poles as their generator: each new pole repeats the previous one
(real pole, or complex pair) with probability 0.05 (not first or last), else is real with probability 0.6
(always real as the last), magnitude U(0.5, 0.97), complex pairs with phase U(0, pi/2) (and conjugate);
A = T^{-1} blockdiag(poles) T with T ~ N(0, 1); B, C entries N(0, 1), each kept with probability 0.8
(redrawn if all are masked). Systems of order n < max_order are padded with inert zero states.

Where we differ, on purpose: their one-step LTI figure (0.009) was trained on python-control's `drss`
(fixed order 10, its own pole law: `LinearDynamicalDataset`), their simulation figure (0.013) on this
generator; we use this one generator for both metrics. Their normalization statistics come from the whole
sequence (non-causal); we keep that, so the normalized outputs are comparable with theirs.

params: LtiSisoParams, the system (A, B, C, order, noise_std) and the normalization y_mean, y_std (B,) of
each trajectory: what a Kalman filter that knows the system needs to predict the normalized outputs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import torch
from torch import Tensor

from mop.errors import check
from mop.systems.base import (
    StateSpace,
    SystemConfig,
    SystemFamily,
    SystemParams,
    Trajectories,
    linear_state_space,
    normal,
    register_family,
    uniform,
)

P_REPEAT, P_REAL, P_BC_MASK, P_D_MASK, P_D_ZERO = 0.05, 0.6, 0.8, 0.3, 0.5
JITTER = 1e-10  # added to the filter's R (and Q) so a noise-free system keeps S = C P C^T + R > 0


def sample_poles(
    order: Tensor,
    max_order: int,
    mag: tuple[float, float],
    phase: tuple[float, float],
    generator: torch.Generator,
) -> tuple[Tensor, Tensor]:
    """(re (B, n), im (B, n)) poles by their drss_matrices rule, n = max_order; positions >= order are 0.
    A complex pair occupies positions i, i+1 with im[i] = -im[i+1]."""
    B = order.shape[0]
    re, im = torch.zeros(B, max_order, dtype=torch.float64), torch.zeros(B, max_order, dtype=torch.float64)
    ptr = torch.zeros(B, dtype=torch.long)
    rows = torch.arange(B)
    for _ in range(max_order):
        active = ptr < order
        r_repeat, r_real = uniform((B,), 0, 1, generator), uniform((B,), 0, 1, generator)
        m, ph = uniform((B,), *mag, generator), uniform((B,), *phase, generator)
        last = ptr == order - 1
        prev = (ptr - 1).clamp(min=0)
        repeat = active & (r_repeat < P_REPEAT) & (ptr != 0) & ~last
        prev_real = im[rows, prev] == 0
        rep_real, rep_pair = repeat & prev_real, repeat & ~prev_real
        real = active & ~repeat & ((r_real < P_REAL) | last)
        pair = active & ~repeat & ~real
        nxt = (ptr + 1).clamp(max=max_order - 1)
        # a repeated real pole copies position i-1; a repeated pair copies positions i-2, i-1
        p2 = (ptr - 2).clamp(min=0)
        re_new = torch.where(rep_real, re[rows, prev], torch.where(rep_pair, re[rows, p2], m * torch.cos(ph)))
        im_new = torch.where(rep_pair, im[rows, p2], m * torch.sin(ph))
        re_new = torch.where(real, m, re_new)
        im_new = torch.where(real | rep_real, torch.zeros_like(im_new), im_new)
        write = active
        re[rows[write], ptr[write]] = re_new[write]
        im[rows[write], ptr[write]] = im_new[write]
        two = rep_pair | pair
        re[rows[two], nxt[two]] = re_new[two]
        im[rows[two], nxt[two]] = -im_new[two]
        ptr = ptr + active.long() + two.long()
    return re, im


def _masked_normal(shape: tuple[int, ...], keep: float, valid: Tensor, generator: torch.Generator) -> Tensor:
    """N(0, 1) entries kept with probability `keep` where `valid` (B, ...), the mask redrawn for systems
    whose valid entries are all masked (their `while not any(mask)`)."""
    values = normal(shape, generator)
    mask = (uniform(shape, 0, 1, generator) < keep) & valid
    for _ in range(1000):
        empty = ~mask.flatten(1).any(1)
        if not empty.any():
            break
        mask[empty] = (uniform((int(empty.sum()), *shape[1:]), 0, 1, generator) < keep) & valid[empty]
    return values * mask


class Drss(NamedTuple):
    """Random systems of sample_drss: A (B, n, n), B (B, n, k), C (B, m, n), D (B, m, k), order (B,)
    (SISO: k = m = 1)."""

    A: Tensor
    B: Tensor
    C: Tensor
    D: Tensor
    order: Tensor


def sample_drss(
    num_systems: int,
    max_order: int,
    strictly_proper: bool,
    generator: torch.Generator,
    mag: tuple[float, float] = (0.5, 0.97),
    phase: tuple[float, float] = (0.0, math.pi / 2),
    random_order: bool = True,
    num_inputs: int = 1,
    num_outputs: int = 1,
) -> Drss:
    """Random stable (A (B, n, n), B (B, n, k), C (B, m, n), D (B, m, k), order (B,)) as their
    drss_matrices, order ~ U{1..max_order} (or max_order), padded to n = max_order with inert states;
    k = num_inputs, m = num_outputs (SISO by default: the same draws as theirs). B's and C's masks are
    redrawn where all its valid entries are masked, as theirs, for each input's column of B and each output's
    row of C (so every input moves the state and every output reads it)."""
    Bn, n = num_systems, max_order
    if random_order:
        order = torch.randint(1, n + 1, (Bn,), generator=generator, device=generator.device).cpu()
    else:
        order = torch.full((Bn,), n, dtype=torch.long)
    re, im = sample_poles(order, n, mag, phase, generator)
    A = torch.diag_embed(re)
    pair_first = torch.zeros(Bn, n, dtype=torch.bool)
    pair_first[:, :-1] = (im[:, :-1] > 0) & (im[:, 1:] == -im[:, :-1])
    b, i = pair_first.nonzero(as_tuple=True)
    A[b, i, i + 1] = im[b, i]
    A[b, i + 1, i] = -im[b, i]
    valid = torch.arange(n)[None] < order[:, None]  # (B, n) states in use
    block = valid[:, :, None] & valid[:, None, :]
    eye = torch.eye(n, dtype=torch.float64).expand(Bn, n, n)
    T = torch.where(block, normal((Bn, n, n), generator), eye)  # identity on the padding
    A = torch.linalg.solve(T, A @ T)  # T^{-1} A T
    k, m = num_inputs, num_outputs
    # each input's column of B and each output's row of C masked (and redrawn) on its own: for k = m = 1
    # the same draws, in the same order, as B (B, n, 1), C (B, 1, n)
    B = _masked_normal((Bn * k, n), P_BC_MASK, valid.repeat_interleave(k, 0), generator)
    B = B.reshape(Bn, k, n).mT
    C = _masked_normal((Bn * m, n), P_BC_MASK, valid.repeat_interleave(m, 0), generator).reshape(Bn, m, n)
    D = normal((Bn, m, k), generator) * (uniform((Bn, m, k), 0, 1, generator) < P_D_MASK)
    D = D * (uniform((Bn, m, k), 0, 1, generator) >= P_D_ZERO)
    if strictly_proper:
        D = torch.zeros_like(D)
    return Drss(A, B, C, D, order)


def lsim(
    A: Tensor, B: Tensor, C: Tensor, D: Tensor, u: Tensor, x0: Tensor | None = None
) -> tuple[Tensor, Tensor]:
    """x_{t+1} = A x_t + B u_t, y_t = C x_t + D u_t (their dlsim), batched: u (B, N, k) ->
    x (B, N, n) (the state at each t), y (B, N, m)."""
    x = u.new_zeros(A.shape[0], A.shape[-1]) if x0 is None else x0
    xs = []
    for t in range(u.shape[1]):
        xs.append(x)
        x = (A @ x[..., None] + B @ u[:, t, :, None])[..., 0]
    X = torch.stack(xs, dim=1)
    return X, X @ C.mT + u @ D.mT


def normalize(y: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """(y - mean) / (std + 1e-6) per trajectory and channel over time (their normalization; numpy's std,
    ddof 0): y (B, N, m) -> (normalized, mean (B, m), std (B, m))."""
    mean, std = y.mean(1), y.std(1, correction=0)
    return (y - mean[:, None]) / (std[:, None] + 1e-6), mean, std


@dataclass(frozen=True)
class LtiSisoConfig(SystemConfig):
    """max_order: orders U{1..max_order}; mag_low/mag_high: pole magnitudes; phase_high: complex-pole phases
    U(0, phase_high); noise_std: white noise on the normalized outputs (theirs: 0 in training, 0.1 in their
    noisy-context test). max_abs is on the normalized outputs and raw states."""

    family: str = "lti-siso"
    max_order: int = 10
    mag_low: float = 0.5
    mag_high: float = 0.97
    phase_high: float = math.pi / 2
    noise_std: float = 0.0
    max_abs: float = 1e6

    def __post_init__(self) -> None:
        super().__post_init__()
        check(
            isinstance(self.max_order, int) and self.max_order >= 1,
            f"system.max_order must be >= 1, got {self.max_order!r}",
        )
        check(
            0 < self.mag_low <= self.mag_high < 1,
            f"system.mag_low/high must satisfy 0 < low <= high < 1, got {self.mag_low}, {self.mag_high}",
        )
        check(0 <= self.phase_high <= math.pi, f"system.phase_high must be in [0, pi], got {self.phase_high}")
        check(self.noise_std >= 0, f"system.noise_std must be >= 0, got {self.noise_std}")


@dataclass(frozen=True)
class LtiSisoSystem(SystemParams):
    """What sample draws: A (B, n, n), B (B, n, 1), C (B, 1, n) (n = max_order, padded), order (B,) long,
    noise_std (B,): the white noise on the normalized outputs (lti-mimo: B (B, n, k), C (B, m, n))."""

    A: Tensor
    B: Tensor
    C: Tensor
    order: Tensor
    noise_std: Tensor


@dataclass(frozen=True)
class LtiSisoParams(LtiSisoSystem):
    """LtiSisoSystem plus each trajectory's normalization y_mean, y_std (B,) (simulate fills them;
    lti-mimo: (B, m), each output's)."""

    y_mean: Tensor
    y_std: Tensor


@register_family("lti-siso", LtiSisoConfig)
class LtiSisoFamily(SystemFamily):
    """Forgione et al.'s random SISO LTI class with white-noise input and per-trajectory normalization.
    Its state is [x; 1] (max_order + 1): the constant carries the normalization offset. params: LtiSisoParams.
    """

    Params = LtiSisoParams

    def __init__(self, config: LtiSisoConfig, dtype: torch.dtype = torch.float32) -> None:
        super().__init__(config, dtype)
        self.state_dim, self.output_dim, self.input_dim = config.max_order + 1, 1, 1  # [x; 1]

    def sample(self, num_systems: int, *, generator: torch.Generator) -> LtiSisoSystem:
        cfg = self.config
        g = sample_drss(
            num_systems,
            cfg.max_order,
            True,
            generator,
            (cfg.mag_low, cfg.mag_high),
            (0.0, cfg.phase_high),
            num_inputs=self.input_dim,
            num_outputs=self.output_dim,
        )
        noise_std = torch.full((num_systems,), cfg.noise_std, dtype=torch.float64)
        return LtiSisoSystem(A=g.A, B=g.B, C=g.C, order=g.order, noise_std=noise_std)

    def simulate(self, params: LtiSisoSystem, horizon: int, *, generator: torch.Generator) -> Trajectories:
        A, B, C = params.A, params.B, params.C
        u = normal((A.shape[0], horizon + 1, 1), generator)
        x, y_raw = lsim(A, B, C, torch.zeros(A.shape[0], 1, 1, dtype=A.dtype), u)
        y, mean, std = normalize(y_raw)
        y = y + self.config.noise_std * normal(tuple(y.shape), generator)
        params = LtiSisoParams.extend(params, y_mean=mean[:, 0], y_std=std[:, 0])
        x = torch.cat([x, torch.ones_like(x[..., :1])], dim=-1)  # the state of state_space: [x; 1]
        return Trajectories(
            y=y.to(self.dtype), u=u.to(self.dtype), x=x.to(self.dtype), params=params, family=self.name
        )

    @staticmethod
    def state_space(params: LtiSisoParams) -> StateSpace:
        """The normalized output as a linear model on [x; 1]: y_t = (C x_t - mean) / (std + 1e-6) + v_t,
        x_0 = 0 known exactly (P0 = 0), Q = 0, R = noise_std^2 (each + JITTER)."""
        p = params
        return normalized_linear_model(p.A, p.B, p.C, p.y_mean, p.y_std, p.noise_std)


def normalized_linear_model(
    A: Tensor,
    B: Tensor,
    C: Tensor,
    mean: Tensor,
    std: Tensor,
    noise_std: Tensor,
    m0: Tensor | None = None,
    P0: Tensor | None = None,
) -> StateSpace:
    """x_aug = [x; 1]: A_aug = blockdiag(A, 1), B_aug = [B; 0], C_aug = [C, -mean] / (std + 1e-6) row by row,
    R = (noise_std^2 + JITTER) I_m. mean, std: (B,) for one output or (B, m); noise_std (B,)."""
    A, B, C = A.double(), B.double(), C.double()
    Bn, n, m = A.shape[0], A.shape[-1], C.shape[-2]
    A_aug = torch.zeros(Bn, n + 1, n + 1, dtype=torch.float64)
    A_aug[:, :n, :n], A_aug[:, n, n] = A, 1.0
    B_aug = torch.cat([B, B.new_zeros(Bn, 1, B.shape[-1])], dim=1)
    scale = (std.double() + 1e-6).reshape(Bn, m, 1)
    C_aug = torch.cat([C, -mean.double().reshape(Bn, m, 1)], dim=-1) / scale
    Q = JITTER * torch.eye(n + 1, dtype=torch.float64).expand(Bn, n + 1, n + 1)
    R = (noise_std.double() ** 2 + JITTER)[:, None, None] * torch.eye(m, dtype=torch.float64)
    if m0 is None:
        m0 = torch.zeros(Bn, n + 1, dtype=torch.float64)
        m0[:, n] = 1.0
    P0 = Q.clone() if P0 is None else P0
    return linear_state_space(A_aug, C_aug, Q, R, P0, B_aug, m0)
