"""Linear Gaussian systems and their variants (the paper's Sec. 5.1):

    x_{t+1} = A x_t + w_t,   y_t = C x_t + v_t,   x_0 ~ N(0, x0_std^2 I),

with w_t ~ N(0, sigma_w^2 I), v_t ~ N(0, sigma_v^2 I) i.i.d., or, for colored noise, w_t and v_t each the sum
of the last `color_window` i.i.d. draws. A is dense (entries U[0,1] scaled to spectral radius rho) or upper
triangular (diagonal U[-rho, rho], strict upper part U[-1, 1]); C has entries U[0,1], redrawn until (A, C) is
observable. Everything is batched over B systems and draws from one torch.Generator on its device.
"""

from __future__ import annotations

import torch
from torch import Tensor

from mop.config import SystemConfig
from mop.errors import MopError
from mop.systems.base import Trajectories

MAX_REDRAWS = 100


def uniform(
    shape: tuple[int, ...],
    low: float,
    high: float,
    generator: torch.Generator,
    dtype: torch.dtype = torch.float64,
) -> Tensor:
    """U[low, high] draws on the generator's device."""
    draw = torch.rand(shape, generator=generator, device=generator.device, dtype=dtype)
    return low + (high - low) * draw


def normal(shape: tuple[int, ...], generator: torch.Generator, dtype: torch.dtype = torch.float64) -> Tensor:
    """N(0, 1) draws on the generator's device (float32 draws are ~4x faster on CPU)."""
    return torch.randn(shape, generator=generator, device=generator.device, dtype=dtype)


def scaled_eye(num_systems: int, dim: int, var: float, device: torch.device) -> Tensor:
    """(B, d, d) var * I in float64."""
    return (var * torch.eye(dim, dtype=torch.float64, device=device)).expand(num_systems, dim, dim).clone()


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


def sample_upper_triangular_A(
    num_systems: int, state_dim: int, spectral_radius: float, generator: torch.Generator
) -> Tensor:
    """(B, n, n) diagonal U[-rho, rho] (the eigenvalues), strictly upper part U[-1, 1], zeros below."""
    check_stable(spectral_radius)
    A = uniform((num_systems, state_dim, state_dim), -1.0, 1.0, generator).triu(1)
    diag = uniform((num_systems, state_dim), -spectral_radius, spectral_radius, generator)
    return A + torch.diag_embed(diag)


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


def out_of_bounds(traj: Trajectories, max_abs: float) -> Tensor:
    """(B,) bool: any |x| or |y| above max_abs (or not finite)."""
    big = lambda t: ~(t.abs() <= max_abs).flatten(1).all(1)  # noqa: E731
    bad = big(traj.y)
    return bad if traj.x is None else bad | big(traj.x)


def generate_with_redraws(family, num_systems: int, horizon: int, generator: torch.Generator) -> Trajectories:
    """sample + simulate, then redraw (sample and simulate again) only the systems that left +-max_abs."""
    if num_systems < 1 or horizon < 1:
        raise MopError(
            f"need at least 1 system and horizon >= 1, got {num_systems} systems, horizon {horizon}"
        )
    traj = family.simulate(family.sample(num_systems, generator=generator), horizon, generator=generator)
    for _ in range(MAX_REDRAWS):
        bad = out_of_bounds(traj, family.config.max_abs)
        if not bad.any():
            return cast(traj, family.dtype)
        idx = bad.nonzero().squeeze(1)
        new = family.simulate(family.sample(len(idx), generator=generator), horizon, generator=generator)
        traj = replace_rows(traj, idx, new)
    raise MopError(
        f"{int(bad.sum())} systems stayed outside |x|,|y| <= {family.config.max_abs} after "
        f"{MAX_REDRAWS} redraws; raise system.max_abs or lower the noise / spectral_radius"
    )


def replace_rows(traj: Trajectories, idx: Tensor, new: Trajectories) -> Trajectories:
    """traj with systems idx replaced by the systems of `new` (same family and horizon)."""

    def put(old: Tensor | None, fresh: Tensor | None) -> Tensor | None:
        if old is None:
            return None
        old = old.clone()
        old[idx] = fresh
        return old

    params = {k: put(v, new.params[k]) for k, v in traj.params.items()}
    return Trajectories(put(traj.y, new.y), put(traj.u, new.u), put(traj.x, new.x), params, traj.family)


def cast(traj: Trajectories, dtype: torch.dtype) -> Trajectories:
    """Floating tensors to dtype (integer params such as switch_time stay as they are)."""
    to = lambda t: None if t is None else (t.to(dtype) if t.is_floating_point() else t)  # noqa: E731
    return Trajectories(
        to(traj.y), to(traj.u), to(traj.x), {k: to(v) for k, v in traj.params.items()}, traj.family
    )


class LinearFamily:
    """Linear Gaussian systems: "linear" (dense A), "upper-triangular", "colored-noise".

    params: "A" (B,n,n), "C" (B,m,n), "Q" (B,n,n) = var(w_t) I, "R" (B,m,m) = var(v_t) I (for colored noise
    the summed variance color_window * sigma^2, as the paper's Kalman filter uses), "P0" (B,n,n) = x0_std^2 I.
    Parameters are drawn in float64 (the spectral radius and observability checks need it); noise and
    simulation run in `dtype`, which generate() returns (float32 for training, float64 for filter references).
    """

    def __init__(self, config: SystemConfig, dtype: torch.dtype = torch.float32) -> None:
        check_stable(config.spectral_radius)
        self.config, self.dtype, self.name = config, dtype, config.family
        self.state_dim = config.state_dim or 10
        self.output_dim = config.output_dim or 5
        self.input_dim = 0
        self.window = config.color_window if config.family == "colored-noise" else 1

    def sample_A(self, num_systems: int, generator: torch.Generator) -> Tensor:
        if self.name == "upper-triangular":
            return sample_upper_triangular_A(
                num_systems, self.state_dim, self.config.spectral_radius, generator
            )
        return sample_dense_A(num_systems, self.state_dim, self.config.spectral_radius, generator)

    def sample(self, num_systems: int, *, generator: torch.Generator) -> dict[str, Tensor]:
        A = self.sample_A(num_systems, generator)  # (B, n, n)
        C = sample_observable_C(A, self.output_dim, generator)  # (B, m, n)
        return {"A": A, "C": C, **self.noise_params(num_systems, A.device)}

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

    def simulate(
        self, params: dict[str, Tensor], horizon: int, *, generator: torch.Generator
    ) -> Trajectories:
        A, C = params["A"].to(self.dtype), params["C"].to(self.dtype)
        x, y = simulate_linear(A, C, *self.draw_noise(A.shape[0], horizon, generator))
        return Trajectories(y=y, x=x, params=dict(params), family=self.name)

    def generate(self, num_systems: int, horizon: int, *, generator: torch.Generator) -> Trajectories:
        return generate_with_redraws(self, num_systems, horizon, generator)
