"""Random Wiener-Hammerstein systems G1 - F - G2 driven by white noise, the family "wiener-hammerstein": the
in-context system-identification class of Forgione, Pura and Piga (github forgi86/sysid-transformers, their
`WHDataset`), re-implemented batched in torch:

    G1: strictly proper SISO, order U{1..max_order} (5), the lti-siso pole law;  y1 normalized by its mean and
        std after a warm-up of `skip` (200) steps;
    F:  q = w2 tanh(w1 y1n + b1) + b2, 32 hidden units, w1 ~ N(0, 1) * 5/3, b1 ~ N(0, 1),
        w2 ~ N(0, 1 / 32), b2 ~ N(0, 1);
    G2: SISO with a direct term D (their non-strictly-proper drss: D = 0 with probability 0.5, else each
        entry kept with probability 0.3), same order and pole law;  y = G2(q) after the warm-up, normalized
        per trajectory (mean, std + 1e-6), then optionally + noise_std * N(0, 1).
Input u_t ~ N(0, 1) i.i.d. The warm-up is simulated and dropped, so x_0 of the kept segment is random.

As a state space for the EKF / UKF (which know the system but not its state), on s = [x1, x2, q, 1]:
    x1' = A1 x1 + B1 u,  q' = F((C1 x1' - mean1) / std1),  x2' = A2 x2 + B2 q,
    y = (C2 x2 + D2 q - mean) / std   (linear in s: the output map stays a matrix),
with s_0 ~ N(m0, P0) the stationary mean and covariance of each system's state, estimated from an
independent run of `skip` + 300 steps with fresh inputs (params m0, P0); Q = R = 1e-10 I jitter
(+ noise_std^2 on R). y_t depends on x1_t through q_t = F(y1n_t), which is why q is a state.

Where we differ: nothing in the generator; the normalization uses the whole kept sequence, as theirs.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from mop.errors import check
from mop.systems.base import StateSpace, SystemFamily, SystemParams, Trajectories, normal, register_family
from mop.systems.lti_siso import JITTER, LtiSisoConfig, lsim, normalize, sample_drss

HIDDEN, SKIP, PRIOR_STEPS = 32, 200, 300


@dataclass(frozen=True)
class WienerHammersteinSystem(SystemParams):
    """What sample draws. F: w1, b1, w2 (B, 32), b2 (B,). G1 (strictly proper): A1 (B, n, n), B1 (B, n, 1),
    C1 (B, 1, n), order1 (B,) long. G2: A2, B2, C2 as G1 and D2 (B, 1, 1), order2 (B,). noise_std (B,).
    (n = max_order, padded with inert states.)"""

    w1: Tensor
    b1: Tensor
    w2: Tensor
    b2: Tensor
    A1: Tensor
    B1: Tensor
    C1: Tensor
    order1: Tensor
    A2: Tensor
    B2: Tensor
    C2: Tensor
    D2: Tensor
    order2: Tensor
    noise_std: Tensor


@dataclass(frozen=True)
class WienerHammersteinParams(WienerHammersteinSystem):
    """The system plus what a simulation gives (simulate fills them): mean1, std1 (B,), the statistics that
    normalize y1; y_mean, y_std (B,), those of the output; m0 (B, 2n+2), P0 (B, 2n+2, 2n+2), the prior of
    the state s = [x1, x2, q, 1]."""

    mean1: Tensor
    std1: Tensor
    y_mean: Tensor
    y_std: Tensor
    m0: Tensor
    P0: Tensor


def static_nonlinearity(z: Tensor, p: WienerHammersteinSystem) -> Tensor:
    """F(z) = w2 tanh(w1 z + b1) + b2 for z (B, N, 1) -> (B, N, 1); w1, b1 (B, 32), w2 (B, 32), b2 (B,)."""
    h = torch.tanh(z * p.w1[:, None] + p.b1[:, None])  # (B, N, 32)
    return (h * p.w2[:, None]).sum(-1, keepdim=True) + p.b2[:, None, None]


@dataclass(frozen=True)
class WienerHammersteinConfig(LtiSisoConfig):
    """The LTI class's pole law, noise and bound (LtiSisoConfig, with its checks) for G1 and G2; max_order:
    orders of G1 and G2, each U{1..max_order}; skip: warm-up steps dropped; noise_std: white noise on the
    normalized outputs (theirs: 0)."""

    family: str = "wiener-hammerstein"
    max_order: int = 5
    skip: int = SKIP

    def __post_init__(self) -> None:
        super().__post_init__()
        check(isinstance(self.skip, int) and self.skip >= 1, f"system.skip must be >= 1, got {self.skip!r}")


@register_family("wiener-hammerstein", WienerHammersteinConfig)
class WienerHammersteinFamily(SystemFamily):
    """Forgione et al.'s random Wiener-Hammerstein class; state [x1, x2, q, 1] (2 max_order + 2).
    params: WienerHammersteinParams."""

    Params = WienerHammersteinParams

    def __init__(self, config: WienerHammersteinConfig, dtype: torch.dtype = torch.float32) -> None:
        super().__init__(config, dtype)
        self.state_dim, self.output_dim, self.input_dim = 2 * config.max_order + 2, 1, 1

    def sample(self, num_systems: int, *, generator: torch.Generator) -> WienerHammersteinSystem:
        cfg, B = self.config, num_systems
        law = ((cfg.mag_low, cfg.mag_high), (0.0, cfg.phase_high))
        w1 = normal((B, HIDDEN), generator) * 5 / 3
        b1 = normal((B, HIDDEN), generator)
        w2 = normal((B, HIDDEN), generator) / HIDDEN**0.5
        b2 = normal((B,), generator)
        g1 = sample_drss(B, cfg.max_order, True, generator, *law)
        g2 = sample_drss(B, cfg.max_order, False, generator, *law)
        return WienerHammersteinSystem(
            w1=w1, b1=b1, w2=w2, b2=b2, A1=g1.A, B1=g1.B, C1=g1.C, order1=g1.order,
            A2=g2.A, B2=g2.B, C2=g2.C, D2=g2.D, order2=g2.order,
            noise_std=torch.full((B,), cfg.noise_std, dtype=torch.float64),
        )  # fmt: skip

    def _run(self, p: WienerHammersteinSystem, u: Tensor) -> dict[str, Tensor]:
        """The cascade over u (B, skip + N, 1); statistics of y1 from after the warm-up (theirs)."""
        skip = self.config.skip
        x1, y1 = lsim(p.A1, p.B1, p.C1, torch.zeros_like(p.C1[..., :1]), u)
        mean1, std1 = y1[:, skip:].mean(1), y1[:, skip:].std(1, correction=0)  # (B, 1)
        q = static_nonlinearity((y1 - mean1[:, None]) / (std1[:, None] + 1e-6), p)
        x2, y3 = lsim(p.A2, p.B2, p.C2, p.D2, q)
        return {"x1": x1, "x2": x2, "q": q, "y3": y3, "mean1": mean1[:, 0], "std1": std1[:, 0]}

    def simulate(
        self, params: WienerHammersteinSystem, horizon: int, *, generator: torch.Generator
    ) -> Trajectories:
        skip, B = self.config.skip, params.A1.shape[0]
        u = normal((B, skip + horizon + 1, 1), generator)
        run = self._run(params, u)
        y, mean, std = normalize(run["y3"][:, skip:])
        y = y + self.config.noise_std * normal(tuple(y.shape), generator)
        ones = torch.ones_like(run["q"])
        state = torch.cat([run["x1"], run["x2"], run["q"], ones], dim=-1)  # (B, skip+T+1, 2n+2)
        m0, P0 = self._prior(params, run["mean1"], run["std1"], generator)
        params = WienerHammersteinParams.extend(
            params, mean1=run["mean1"], std1=run["std1"], y_mean=mean[:, 0], y_std=std[:, 0], m0=m0, P0=P0
        )
        return Trajectories(
            y=y.to(self.dtype),
            u=u[:, skip:].to(self.dtype),
            x=state[:, skip:].to(self.dtype),
            params=params,
            family=self.name,
        )

    def _prior(self, p, mean1, std1, generator) -> tuple[Tensor, Tensor]:
        """m0 (B, d), P0 (B, d, d): the mean and covariance of s over steps skip..skip+PRIOR_STEPS of an
        independent run with fresh inputs (y1 normalized with the test run's statistics, as the model)."""
        skip, B = self.config.skip, mean1.shape[0]
        u = normal((B, skip + PRIOR_STEPS, 1), generator)
        x1, y1 = lsim(p.A1, p.B1, p.C1, torch.zeros_like(p.C1[..., :1]), u)
        q = static_nonlinearity((y1 - mean1[:, None, None]) / (std1[:, None, None] + 1e-6), p)
        x2, _ = lsim(p.A2, p.B2, p.C2, p.D2, q)
        s = torch.cat([x1, x2, q], dim=-1)[:, skip:]  # (B, N, 2n+1)
        m = s.mean(1)
        d = s - m[:, None]
        P = d.mT @ d / s.shape[1]
        n = s.shape[-1] + 1
        m0 = torch.cat([m, torch.ones(B, 1, dtype=m.dtype)], dim=-1)
        P0 = torch.zeros(B, n, n, dtype=m.dtype)
        P0[:, :-1, :-1] = P
        return m0, P0 + JITTER * torch.eye(n, dtype=m.dtype)

    @staticmethod
    def state_space(params: WienerHammersteinParams) -> StateSpace:
        """The cascade on s = [x1, x2, q, 1] (the module docstring); f and its Jacobian by formula."""
        p = params.map(Tensor.double)
        n = p.A1.shape[-1]
        A1, B1, C1, A2, B2, C2, D2 = p.A1, p.B1, p.C1, p.A2, p.B2, p.C2, p.D2
        mean1, scale1 = p.mean1[:, None, None], (p.std1 + 1e-6)[:, None, None]

        def f(s: Tensor, u: Tensor | None, t: int) -> Tensor:  # s (B, N, 2n+2), u (B, N, 1)
            x1, x2, q, one = s[..., :n], s[..., n : 2 * n], s[..., 2 * n : 2 * n + 1], s[..., -1:]
            x1n = x1 @ A1.mT + (0 if u is None else u @ B1.mT)
            q_next = static_nonlinearity((x1n @ C1.mT - mean1) / scale1, p)
            return torch.cat([x1n, x2 @ A2.mT + q @ B2.mT, q_next, one], dim=-1)

        Bn, d = A1.shape[0], 2 * n + 2

        def jacobian(s: Tensor, u: Tensor | None, t: int) -> Tensor:  # s (B, d), u (B, 1) -> (B, d, d)
            x1 = s[:, :n]
            x1n = (A1 @ x1[..., None])[..., 0] + (0 if u is None else (B1 @ u[..., None])[..., 0])
            z = ((C1 @ x1n[..., None])[..., 0] - mean1[:, 0]) / scale1[:, 0]  # (B, 1)
            sech2 = 1 - torch.tanh(z * p.w1 + p.b1) ** 2  # (B, 32)
            dF = (p.w2 * p.w1 * sech2).sum(-1)  # (B,)
            J = s.new_zeros(Bn, d, d)
            J[:, :n, :n] = A1
            J[:, n : 2 * n, n : 2 * n] = A2
            J[:, n : 2 * n, 2 * n] = B2[..., 0]
            J[:, 2 * n, :n] = dF[:, None] * (C1 @ A1)[:, 0] / scale1[:, 0]
            J[:, -1, -1] = 1.0
            return J

        scale = (p.y_std + 1e-6)[:, None, None]
        C = torch.cat([torch.zeros_like(C2), C2, D2, -p.y_mean[:, None, None]], dim=-1) / scale
        Q = JITTER * torch.eye(d, dtype=torch.float64).expand(Bn, d, d)
        R = (p.noise_std**2 + JITTER)[:, None, None]
        return StateSpace(f=f, C=C, Q=Q, R=R, m0=p.m0, P0=p.P0, jacobian=jacobian)
