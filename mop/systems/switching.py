"""Switching linear systems (the paper's Fig. 3(b)): a fresh system takes over at switch_time s,
continuing from the current state:

    x_{t+1} = A_t x_t + w_t,  y_t = C_t x_t + v_t,  (A_t, C_t) = (A, C) for t < s, (A2, C2) for t >= s.

So y_0..y_{s-1} come from system 1 and the state x_s (reached with system 1) is system 2's initial state.
Both systems are dense linear systems drawn as in mop.systems.linear (the paper tests on 100 steps).
"""

from __future__ import annotations

import torch
from torch import Tensor

from mop.config import SystemConfig
from mop.systems.base import Trajectories
from mop.systems.linear import LinearFamily, sample_dense_A, sample_observable_C, simulate_linear


class SwitchingFamily(LinearFamily):
    """params: "A", "C" (system 1), "A2", "C2" (system 2), "Q", "R", "P0", "switch_time" (B,) long."""

    def __init__(self, config: SystemConfig, dtype: torch.dtype = torch.float32) -> None:
        super().__init__(config, dtype)
        self.window = 1

    def sample(self, num_systems: int, *, generator: torch.Generator) -> dict[str, Tensor]:
        params = super().sample(num_systems, generator=generator)
        A2 = sample_dense_A(num_systems, self.state_dim, self.config.spectral_radius, generator)
        C2 = sample_observable_C(A2, self.output_dim, generator)
        switch = torch.full((num_systems,), self.config.switch_time, dtype=torch.long, device=A2.device)
        return {**params, "A2": A2, "C2": C2, "switch_time": switch}

    def simulate(
        self, params: dict[str, Tensor], horizon: int, *, generator: torch.Generator
    ) -> Trajectories:
        A, C = params["A"].to(self.dtype), params["C"].to(self.dtype)
        s = params["switch_time"]
        if not bool((s == s[0]).all()):
            raise ValueError("SwitchingFamily.simulate needs one switch_time for the whole batch")
        x0, w, v = self.draw_noise(A.shape[0], horizon, generator)
        x, y = simulate_linear(
            A, C, x0, w, v, params["A2"].to(self.dtype), params["C2"].to(self.dtype), int(s[0])
        )
        return Trajectories(y=y, x=x, params=dict(params), family=self.name)
