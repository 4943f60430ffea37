"""Training and validation batches: inputs z_0..z_{T-1} (B, T, d_in), targets y_1..y_T (B, T, m).

num_source_systems = M > 0 draws M systems with one trajectory each once (on the training device) and samples
batches from them with a seeded generator; M = 0 draws fresh systems every batch. All training randomness
comes from one torch.Generator (saved in every checkpoint), so the same seed gives the same weights.
"""

from __future__ import annotations

import torch
from torch import Tensor

from mop.config import RunConfig
from mop.systems import make_family

NUM_VAL_SYSTEMS = 256


class TrainingData:
    """Batches of (inputs (B, T, d_in), targets (B, T, m)) on `device`, all randomness from one generator."""

    def __init__(self, config: RunConfig, device: torch.device) -> None:
        self.family, self.cfg = make_family(config.system), config.train
        self.generator = torch.Generator(device=device).manual_seed(self.cfg.seed)
        self.inputs = self.targets = None
        if self.cfg.num_source_systems > 0:
            self.inputs, self.targets = self._draw(self.cfg.num_source_systems)  # (M, T, d_in), (M, T, m)

    def _draw(self, num_systems: int) -> tuple[Tensor, Tensor]:
        traj = self.family.generate(num_systems, self.cfg.horizon, generator=self.generator)
        z = traj.model_inputs()  # (B, T+1, d_in)
        return z[:, :-1].float().contiguous(), traj.y[:, 1:].float().contiguous()

    def batch(self) -> tuple[Tensor, Tensor]:
        if self.inputs is None:
            return self._draw(self.cfg.batch_size)
        index = torch.randint(
            0,
            self.inputs.shape[0],
            (self.cfg.batch_size,),
            generator=self.generator,
            device=self.generator.device,
        )
        return self.inputs[index], self.targets[index]


def validation_batch(config: RunConfig, device: torch.device) -> tuple[Tensor, Tensor]:
    """Held-out systems (a generator seeded apart from training) for the validation loss."""
    family = make_family(config.system)
    g = torch.Generator(device=device).manual_seed(config.train.seed + 1_000_003)
    traj = family.generate(NUM_VAL_SYSTEMS, config.train.horizon, generator=g)
    return traj.model_inputs()[:, :-1].float(), traj.y[:, 1:].float()  # (N, T, d_in), (N, T, m)
