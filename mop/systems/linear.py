"""Linear Gaussian systems, the family "linear" (the paper's Sec. 5.1), and the helpers its variants share:

    x_{t+1} = A x_t + w_t,   y_t = C x_t + v_t,   x_0 ~ N(0, x0_std^2 I),

with w_t ~ N(0, sigma_w^2 I), v_t ~ N(0, sigma_v^2 I) i.i.d. A is dense (entries U[0,1] scaled to spectral
radius rho); C has entries U[0,1], redrawn until (A, C) is observable. Everything is batched over B systems
and draws from one torch.Generator on its device. Variants (upper_triangular, colored_noise, switching)
subclass LinearFamily in their own modules.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from mop.errors import MopError, check
from mop.systems.base import (
    MAX_REDRAWS,
    StateSpace,
    SystemConfig,
    SystemFamily,
    SystemParams,
    Trajectories,
    linear_state_space,
    normal,
    register_family,
    scaled_eye,
    uniform,
)


def check_stable(spectral_radius: float) -> None:
    if not 0 < spectral_radius < 1:
        raise MopError(f"spectral_radius must be in (0, 1) for a stable system, got {spectral_radius}")


def perron_radius(A: Tensor, num_iters: int = 25) -> Tensor:
    """(B,) spectral radius of entrywise positive A (B, n, n) by power iteration.

    For A > 0 the Perron root is real, simple and strictly dominant (Perron-Frobenius), so ||A v|| / ||v||
    converges like |lambda_2 / lambda_1|^k (about 0.2^k for 10 x 10 U[0,1] matrices: 25 steps reach float64
    rounding); 25 batched mat-vecs are far cheaper than a batched eigendecomposition.
    """
    v = torch.ones(A.shape[:-1], dtype=A.dtype, device=A.device)  # (B, n)
    for _ in range(num_iters):
        v = torch.einsum("bij,bj->bi", A, v)
        v = v / v.norm(dim=-1, keepdim=True)
    return torch.einsum("bij,bj->bi", A, v).norm(dim=-1)


def sample_dense_A(
    num_systems: int, state_dim: int, spectral_radius: float, generator: torch.Generator
) -> Tensor:
    """(B, n, n) entries U[0,1], scaled so that max |eig(A)| = spectral_radius."""
    check_stable(spectral_radius)
    A = uniform((num_systems, state_dim, state_dim), 0.0, 1.0, generator)
    rho = perron_radius(A)  # (B,)
    return A * (spectral_radius / rho)[:, None, None]


def observability_matrix(A: Tensor, C: Tensor, num_blocks: int | None = None) -> Tensor:
    """(B, k*m, n) [C; C A; ...; C A^{k-1}], k = num_blocks (default n: the full observability matrix)."""
    blocks, CAk = [C], C
    for _ in range((num_blocks or A.shape[-1]) - 1):
        CAk = CAk @ A
        blocks.append(CAk)
    return torch.cat(blocks, dim=-2)


def full_column_rank(O: Tensor) -> Tensor:
    """(B,) bool: O (B, r, n) has rank n, i.e. the Gram G = O^T O has lambda_min(G) > tol.

    tol = trace(G) * max(r, n) * eps (trace(G) bounds sigma_max(O)^2; the Gram resolves singular values
    only down to sqrt(eps) * sigma_max). lambda_min(G) > tol iff G - tol I is positive definite, which a
    batched Cholesky decides far faster than an eigendecomposition.
    """
    G = O.mT @ O  # (B, n, n)
    tol = G.diagonal(dim1=-2, dim2=-1).sum(-1) * max(O.shape[-2:]) * torch.finfo(O.dtype).eps  # (B,)
    eye = torch.eye(G.shape[-1], dtype=G.dtype, device=G.device)
    return torch.linalg.cholesky_ex(G - tol[:, None, None] * eye).info == 0


def is_observable(A: Tensor, C: Tensor) -> Tensor:
    """(B,) bool: the observability matrix [C; C A; ...; C A^{n-1}] has full column rank n.

    The first ceil(n/m) blocks already have rank n for almost every system (and then so does the whole
    matrix); only the systems where they do not get the full n-block check.
    """
    n, m = A.shape[-1], C.shape[-2]
    k = -(-n // m)
    ok = full_column_rank(observability_matrix(A, C, k))
    if k < n and not ok.all():
        idx = (~ok).nonzero().squeeze(1)
        ok[idx] = full_column_rank(observability_matrix(A[idx], C[idx]))
    return ok


def sample_observable_C(A: Tensor, output_dim: int, generator: torch.Generator) -> Tensor:
    """(B, m, n) entries U[0,1], redrawn (only for the failing systems) until (A, C) is observable."""
    B, n = A.shape[0], A.shape[-1]
    C = uniform((B, output_dim, n), 0.0, 1.0, generator)
    for _ in range(MAX_REDRAWS):
        bad = ~is_observable(A, C)
        if not bad.any():
            return C
        C[bad] = uniform((int(bad.sum()), output_dim, n), 0.0, 1.0, generator)
    raise MopError(
        f"could not draw an observable C for {int(bad.sum())} systems in {MAX_REDRAWS} tries; "
        "check state_dim/output_dim"
    )


def moving_sum_noise(
    num_systems: int,
    horizon: int,
    dim: int,
    var: float,
    window: int,
    generator: torch.Generator,
    dtype: torch.dtype = torch.float64,
) -> Tensor:
    """(B, T+1, d) noise e_t = sum_{j=0}^{window-1} eps_{t-j}, eps i.i.d. N(0, var I); window 1: white."""
    eps = normal((num_systems, horizon + window, dim), generator, dtype).mul_(var**0.5)  # (B, T+window, d)
    e = eps[:, : horizon + 1]
    for j in range(1, window):  # a sum of shifted slices: exact, unlike differences of a cumsum
        e = e + eps[:, j : j + horizon + 1]
    return e


def simulate_linear(
    A: Tensor,
    C: Tensor,
    x0: Tensor,
    w: Tensor,
    v: Tensor,
    A2: Tensor | None = None,
    C2: Tensor | None = None,
    switch_time: int | None = None,
) -> tuple[Tensor, Tensor]:
    """x_{t+1} = A_t x_t + w_t, y_t = C_t x_t + v_t for t = 0..T; a loop over time only.

    A_t, C_t are (A, C) for t < switch_time and (A2, C2) from then on (no switch when A2 is None).
    x0: (B, n); w: (B, T+1, n) (w_T unused); v: (B, T+1, m). Returns x (B, T+1, n), y (B, T+1, m).
    """
    num_steps = v.shape[1]
    xs, x = [x0], x0
    for t in range(num_steps - 1):
        At = A if A2 is None or t < switch_time else A2
        x = torch.baddbmm(w[:, t, :, None], At, x[..., None])[..., 0]  # (B, n)
        xs.append(x)
    x = torch.stack(xs, dim=1)  # (B, T+1, n)
    if A2 is None:
        return x, torch.baddbmm(v, x, C.mT)
    y = torch.cat([x[:, :switch_time] @ C.mT, x[:, switch_time:] @ C2.mT], dim=1)
    return x, y + v


@dataclass(frozen=True)
class LinearConfig(SystemConfig):
    """Linear Gaussian systems (the paper's defaults). noise_var_w / noise_var_v: variance of each i.i.d.
    noise draw (sigma^2, the paper's 0.01); x0_std: x_0 ~ N(0, x0_std^2 I); spectral_radius: max |eig(A)|."""

    family: str = "linear"
    state_dim: int = 10
    output_dim: int = 5
    noise_var_w: float = 0.01
    noise_var_v: float = 0.01
    spectral_radius: float = 0.95
    x0_std: float = 1.0

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("state_dim", "output_dim"):
            value = getattr(self, name)
            check(
                isinstance(value, int) and value > 0,
                f"system.{name} must be a positive integer, got {value!r}",
            )
        check(
            self.noise_var_w >= 0 and self.noise_var_v >= 0,
            f"noise variances must be >= 0, got w={self.noise_var_w}, v={self.noise_var_v}",
        )
        check(
            0 < self.spectral_radius < 1,
            f"system.spectral_radius must be in (0, 1) for a stable system, got {self.spectral_radius}",
        )
        check(self.x0_std >= 0, f"system.x0_std must be >= 0, got {self.x0_std}")


@dataclass(frozen=True)
class LinearParams(SystemParams):
    """x_{t+1} = A x_t + w_t, y_t = C x_t + v_t, x_0 ~ N(0, P0), per system:

    A (B, n, n); C (B, m, n); Q (B, n, n) = var(w_t) I and R (B, m, m) = var(v_t) I (for colored noise the
    summed variance color_window * sigma^2, as the paper's Kalman filter uses); P0 (B, n, n) = x0_std^2 I;
    noise_var_w, noise_var_v (B,) float64: the variance of one noise draw; color_window (B,) long: the draws
    summed per step (1: white; the exact colored-noise filter, mop.filters.colored, reads these three)."""

    A: Tensor
    C: Tensor
    Q: Tensor
    R: Tensor
    P0: Tensor
    noise_var_w: Tensor
    noise_var_v: Tensor
    color_window: Tensor


@register_family("linear", LinearConfig, default=True)
class LinearFamily(SystemFamily):
    """Dense linear Gaussian systems (the paper's Fig. 2a); the base of the other linear families.

    params: LinearParams. Parameters are drawn in float64 (the spectral radius and observability checks need
    it); noise and simulation run in `dtype`, which generate() returns (float32 for training, float64 for
    filter references).
    """

    Params = LinearParams
    window = 1  # noise draws summed per step (colored noise: color_window)

    def __init__(self, config: LinearConfig, dtype: torch.dtype = torch.float32) -> None:
        super().__init__(config, dtype)
        check_stable(config.spectral_radius)  # also when a config was changed behind its validation
        self.state_dim, self.output_dim, self.input_dim = config.state_dim, config.output_dim, 0

    def sample_A(self, num_systems: int, generator: torch.Generator) -> Tensor:
        return sample_dense_A(num_systems, self.state_dim, self.config.spectral_radius, generator)

    def sample(self, num_systems: int, *, generator: torch.Generator) -> LinearParams:
        A = self.sample_A(num_systems, generator)  # (B, n, n)
        C = sample_observable_C(A, self.output_dim, generator)  # (B, m, n)
        return LinearParams(A=A, C=C, **self.noise_params(num_systems, A.device))

    def noise_params(self, num_systems: int, device: torch.device) -> dict[str, Tensor]:
        """Q, R (summed variances), P0; and for the exact colored-noise filter (mop.filters.colored) the
        per-draw variances "noise_var_w", "noise_var_v" (B,) float64 and "color_window" (B,) long."""
        eye = lambda d, var: scaled_eye(num_systems, d, var, device)  # noqa: E731
        full = lambda v, dt: torch.full((num_systems,), v, dtype=dt, device=device)  # noqa: E731
        cfg, n, m = self.config, self.state_dim, self.output_dim
        return {
            "Q": eye(n, cfg.noise_var_w * self.window).clone(),
            "R": eye(m, cfg.noise_var_v * self.window).clone(),
            "P0": eye(n, cfg.x0_std**2).clone(),
            "noise_var_w": full(cfg.noise_var_w, torch.float64),
            "noise_var_v": full(cfg.noise_var_v, torch.float64),
            "color_window": full(self.window, torch.long),
        }

    def draw_noise(
        self, num_systems: int, horizon: int, generator: torch.Generator
    ) -> tuple[Tensor, Tensor, Tensor]:
        """x0 (B, n), w (B, T+1, n), v (B, T+1, m)."""
        cfg, n, m = self.config, self.state_dim, self.output_dim
        x0 = normal((num_systems, n), generator, self.dtype) * cfg.x0_std
        w = moving_sum_noise(num_systems, horizon, n, cfg.noise_var_w, self.window, generator, self.dtype)
        v = moving_sum_noise(num_systems, horizon, m, cfg.noise_var_v, self.window, generator, self.dtype)
        return x0, w, v

    def simulate(self, params: LinearParams, horizon: int, *, generator: torch.Generator) -> Trajectories:
        A, C = params.A.to(self.dtype), params.C.to(self.dtype)
        x, y = simulate_linear(A, C, *self.draw_noise(A.shape[0], horizon, generator))
        return Trajectories(y=y, x=x, params=params, family=self.name)

    @staticmethod
    def state_space(params: LinearParams) -> StateSpace:
        """x_{t+1} = A x_t + w_t, y_t = C x_t + v_t with the white Q, R of params (for colored noise the
        summed variances: the paper's Kalman filter, which treats the noise as white)."""
        p = params
        return linear_state_space(p.A, p.C, p.Q, p.R, p.P0)
