"""Random LTI systems with several outputs (and inputs) driven by white noise, the family "lti-mimo": the
lti-siso class (mop.systems.lti_siso, Forgione et al.'s generator) with k inputs and m outputs,

    x_{t+1} = A x_t + B u_t,   y_t = C x_t (strictly proper),   x_0 = 0,   u_t ~ N(0, I_k) i.i.d.,
    each output normalized per trajectory: (y - mean_t y) / (std_t y + 1e-6) over all T + 1 outputs,
    then + noise_std * N(0, I_m) on the normalized outputs.

A, its order n ~ U{1..max_order} and its poles are drawn by lti-siso's law; each input's column of B and
each output's row of C has N(0, 1) entries kept with probability 0.8 (redrawn where all are masked), so every
input moves the state and every output reads it, and the outputs share the system's modes. The defaults,
one input and three outputs, are a structure under test with one shaker and several accelerometers (the
F-16 ground vibration test's). With k = m = 1 the draws are exactly lti-siso's.

params: lti-siso's types (LtiSisoSystem, LtiSisoParams), with B (B, n, k), C (B, m, n) and each output's
normalization y_mean, y_std (B, m); the state space is lti-siso's (mop.systems.lti_siso.
normalized_linear_model, row by row): what a Kalman filter that knows the system needs to predict the
normalized outputs.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from mop.errors import check_int
from mop.systems.base import Trajectories, normal, register_family
from mop.systems.lti_siso import (
    LtiSisoConfig,
    LtiSisoFamily,
    LtiSisoParams,
    LtiSisoSystem,
    lsim,
    normalize,
)


@dataclass(frozen=True)
class LtiMimoConfig(LtiSisoConfig):
    """LtiSisoConfig plus num_inputs (k) and num_outputs (m)."""

    family: str = "lti-mimo"
    num_inputs: int = 1
    num_outputs: int = 3

    def __post_init__(self) -> None:
        super().__post_init__()
        for key in ("num_inputs", "num_outputs"):
            check_int(f"system.{key}", getattr(self, key), 1)


@register_family("lti-mimo", LtiMimoConfig)
class LtiMimoFamily(LtiSisoFamily):
    """The lti-siso class with k inputs and m outputs. Its state is [x; 1] (max_order + 1): the constant
    carries the normalization offsets. params: lti-siso's LtiSisoParams, with y_mean, y_std (B, m); its
    sample and state_space are lti-siso's (for k inputs and m outputs, row by row)."""

    def __init__(self, config: LtiMimoConfig, dtype: torch.dtype = torch.float32) -> None:
        super().__init__(config, dtype)
        # lti-siso's sample draws B and C of these widths
        self.output_dim, self.input_dim = config.num_outputs, config.num_inputs

    def simulate(self, params: LtiSisoSystem, horizon: int, *, generator: torch.Generator) -> Trajectories:
        A, B, C = params.A, params.B, params.C
        m, k = C.shape[1], B.shape[2]
        u = normal((A.shape[0], horizon + 1, k), generator)
        x, y_raw = lsim(A, B, C, torch.zeros(A.shape[0], m, k, dtype=A.dtype), u)
        y, mean, std = normalize(y_raw)
        y = y + self.config.noise_std * normal(tuple(y.shape), generator)
        params = LtiSisoParams.extend(params, y_mean=mean, y_std=std)
        x = torch.cat([x, torch.ones_like(x[..., :1])], dim=-1)  # the state of state_space: [x; 1]
        return Trajectories(
            y=y.to(self.dtype), u=u.to(self.dtype), x=x.to(self.dtype), params=params, family=self.name
        )
