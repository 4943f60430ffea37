"""Linear Gaussian systems driven by known inputs, the family "linear-inputs":

    x_{t+1} = A x_t + B u_t + w_t,   y_t = C x_t + v_t,   x_0 ~ N(0, x0_std^2 I),

A, C, w, v as the family "linear"; B (n x k) has i.i.d. entries N(0, input_gain^2 / n) (so ||B u|| does not
grow with n), and the inputs u_t ~ N(0, input_std^2 I) are i.i.d. white (persistently exciting), drawn for
t = 0..T (u_T moves nothing; a learned predictor reads [y_t, u_t]). The Kalman filter that knows (A, B, C,
Q, R, P0) is the optimal one-step predictor; its time update is m <- A m + B u_t.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from mop.errors import check
from mop.systems.base import StateSpace, Trajectories, linear_state_space, normal, register_family
from mop.systems.linear import LinearConfig, LinearFamily, LinearParams, simulate_linear


@dataclass(frozen=True)
class LinearInputsConfig(LinearConfig):
    """LinearConfig plus input_dim (k), input_std (u_t ~ N(0, input_std^2 I)) and input_gain
    (B entries N(0, input_gain^2 / n))."""

    family: str = "linear-inputs"
    input_dim: int = 2
    input_std: float = 1.0
    input_gain: float = 1.0

    def __post_init__(self) -> None:
        super().__post_init__()
        check(
            isinstance(self.input_dim, int) and self.input_dim > 0,
            f"system.input_dim must be a positive integer, got {self.input_dim!r}",
        )
        check(self.input_std >= 0, f"system.input_std must be >= 0, got {self.input_std}")
        check(self.input_gain >= 0, f"system.input_gain must be >= 0, got {self.input_gain}")


@dataclass(frozen=True)
class LinearInputsParams(LinearParams):
    """LinearParams plus the input matrix B (B, n, k): x_{t+1} = A x_t + B u_t + w_t."""

    B: Tensor


@register_family("linear-inputs", LinearInputsConfig)
class LinearInputsFamily(LinearFamily):
    """Dense linear Gaussian systems with inputs. params: LinearInputsParams."""

    Params = LinearInputsParams

    def __init__(self, config: LinearInputsConfig, dtype: torch.dtype = torch.float32) -> None:
        super().__init__(config, dtype)
        self.input_dim = config.input_dim

    def sample(self, num_systems: int, *, generator: torch.Generator) -> LinearInputsParams:
        params = super().sample(num_systems, generator=generator)
        scale = self.config.input_gain / self.state_dim**0.5
        B = normal((num_systems, self.state_dim, self.input_dim), generator) * scale
        return LinearInputsParams.extend(params, B=B)

    def simulate(
        self, params: LinearInputsParams, horizon: int, *, generator: torch.Generator
    ) -> Trajectories:
        A, B, C = (M.to(self.dtype) for M in (params.A, params.B, params.C))
        x0, w, v = self.draw_noise(A.shape[0], horizon, generator)
        u = normal((A.shape[0], horizon + 1, self.input_dim), generator, self.dtype) * self.config.input_std
        x, y = simulate_linear(A, C, x0, w + u @ B.mT, v)  # the input enters as a known forcing B u_t
        return Trajectories(y=y, u=u, x=x, params=params, family=self.name)

    @staticmethod
    def state_space(params: LinearInputsParams) -> StateSpace:
        """x_{t+1} = A x_t + B u_t + w_t, y_t = C x_t + v_t, x_0 ~ N(0, P0)."""
        p = params
        return linear_state_space(p.A, p.C, p.Q, p.R, p.P0, B=p.B)
