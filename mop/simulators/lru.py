"""The linear recurrent unit (LRU, Orvieto et al., "Resurrecting recurrent neural networks for long
sequences", ICML 2023) and a deep stack of them, the body of the deep-LRU system identifiers (Forgione,
Mejari, Piga, CDC 2024).

One LRU layer, width H (its inputs and outputs), state N (complex):

    x_t = lambda * x_{t-1} + gamma * (B u_t),   y_t = Re(C x_t) + D * u_t
    lambda = exp(-exp(nu) + i exp(theta))  (|lambda| < 1: stable by construction)
    gamma = sqrt(1 - |lambda|^2)

`forward` computes every x_t at once by an associative (Hillis-Steele) scan over time, log2(T) elementwise
steps; `loop` computes them one step at a time. They are equal (tests/test_simulators.py).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn


def linear_scan(lam: Tensor, b: Tensor, h0: Tensor | None = None) -> Tensor:
    """x (B, T, N) with x_t = lam * x_{t-1} + b_t and x_{-1} = h0 (B, N) (zero where None); lam (N,)."""
    x = b.clone()
    a = lam.expand(b.shape[1], -1).clone()  # (T, N): a_t = the product of the lams folded into x_t so far
    step = 1
    while step < b.shape[1]:
        x = torch.cat([x[:, :step], x[:, step:] + a[step:] * x[:, :-step]], dim=1)
        a = torch.cat([a[:step], a[step:] * a[:-step]], dim=0)
        step *= 2
    if h0 is not None:
        x = x + a * h0[:, None]  # a_t = lam^(t+1): the initial state carried to step t
    return x


class LRU(nn.Module):
    """One linear recurrent unit (see the module docstring); r_min, r_max bound |lambda| at initialisation,
    max_phase its angle."""

    def __init__(
        self, width: int, state: int, r_min: float = 0.5, r_max: float = 0.99, max_phase: float = math.pi / 4
    ) -> None:
        super().__init__()
        u1, u2 = torch.rand(state), torch.rand(state)
        nu = -0.5 * torch.log(u1 * (r_max**2 - r_min**2) + r_min**2)
        self.nu_log = nn.Parameter(torch.log(nu))
        self.theta_log = nn.Parameter(torch.log(max_phase * u2 + 1e-6))
        self.B_re = nn.Parameter(torch.randn(state, width) / math.sqrt(2 * width))
        self.B_im = nn.Parameter(torch.randn(state, width) / math.sqrt(2 * width))
        self.C_re = nn.Parameter(torch.randn(width, state) / math.sqrt(state))
        self.C_im = nn.Parameter(torch.randn(width, state) / math.sqrt(state))
        self.D = nn.Parameter(torch.randn(width) / math.sqrt(width))
        self.state_dim = state

    def lam(self) -> Tensor:
        """lambda (N,), complex."""
        return torch.exp(torch.complex(-torch.exp(self.nu_log), torch.exp(self.theta_log)))

    def _drive(self, u: Tensor) -> tuple[Tensor, Tensor]:
        lam = self.lam()
        gamma = torch.sqrt(1 - lam.abs() ** 2)
        B = torch.complex(self.B_re, self.B_im)
        return lam, (u.to(B.dtype) @ B.T) * gamma  # (N,), (B, T, N)

    def _read(self, x: Tensor, u: Tensor) -> Tensor:
        C = torch.complex(self.C_re, self.C_im)
        return (x @ C.T).real + self.D * u

    def forward(self, u: Tensor, h0: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """u (B, T, H) -> (y (B, T, H), x_{T-1} (B, N)), by the parallel scan."""
        lam, b = self._drive(u)
        x = linear_scan(lam, b, h0)
        return self._read(x, u), x[:, -1]

    def loop(self, u: Tensor, h0: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """forward, one step at a time (the reference the scan is tested against)."""
        lam, b = self._drive(u)
        x = torch.zeros_like(b[:, 0]) if h0 is None else h0
        states = []
        for t in range(b.shape[1]):
            x = lam * x + b[:, t]
            states.append(x)
        return self._read(torch.stack(states, dim=1), u), x


class DeepLRU(nn.Module):
    """inputs (B, T, k) -> outputs (B, T, m): a linear read-in to width H, L blocks of [LayerNorm, LRU,
    GELU, a gated linear unit] with a residual connection each, a linear read-out. The blocks' initial
    states (L of them, (B, N) complex each) are given as h0, a list, or start at zero."""

    def __init__(self, inputs: int, outputs: int, width: int, state: int, layers: int) -> None:
        super().__init__()
        self.read_in = nn.Linear(inputs, width)
        self.norms = nn.ModuleList(nn.LayerNorm(width) for _ in range(layers))
        self.lrus = nn.ModuleList(LRU(width, state) for _ in range(layers))
        self.glus = nn.ModuleList(nn.Linear(width, 2 * width) for _ in range(layers))
        self.read_out = nn.Linear(width, outputs)
        self.state_dim, self.layers = state, layers

    def forward(self, u: Tensor, h0: list[Tensor] | None = None, loop: bool = False) -> Tensor:
        z = self.read_in(u)
        for i in range(self.layers):
            lru = self.lrus[i]
            y, _ = (lru.loop if loop else lru)(self.norms[i](z), None if h0 is None else h0[i])
            z = z + nn.functional.glu(self.glus[i](nn.functional.gelu(y)), dim=-1)
        return self.read_out(z)
