"""Linear systems with colored noise (the paper's Fig. 2b): w_t and v_t are each the sum of the last
`color_window` i.i.d. N(0, sigma^2 I) draws, so consecutive noises are correlated. The paper's Kalman filter
(the family's state_space) treats the noise as white with the summed variance color_window * sigma^2; the
exact optimum is the "kalman-colored" predictor (mop.filters.colored)."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from mop.errors import check
from mop.systems.base import register_family
from mop.systems.linear import LinearConfig, LinearFamily


@dataclass(frozen=True)
class ColoredNoiseConfig(LinearConfig):
    family: str = "colored-noise"
    color_window: int = 5

    def __post_init__(self) -> None:
        super().__post_init__()
        check(self.color_window >= 1, f"system.color_window must be >= 1, got {self.color_window}")


@register_family("colored-noise", ColoredNoiseConfig)
class ColoredNoiseFamily(LinearFamily):
    exact_state_space = False  # state_space is the white-noise approximation (the paper's KF)

    def __init__(self, config: ColoredNoiseConfig, dtype: torch.dtype = torch.float32) -> None:
        super().__init__(config, dtype)
        self.window = config.color_window
