"""Zero and last-value baselines: exact definitions."""

import torch

from mop.filters.simple import LastValuePredictor, ZeroPredictor
from mop.systems.base import Trajectories


def test_zero_and_last_value():
    y = torch.randn(3, 7, 2, generator=torch.Generator().manual_seed(0))
    traj = Trajectories(y=y)
    assert torch.equal(ZeroPredictor().predict(traj), torch.zeros_like(y))
    last = LastValuePredictor().predict(traj)
    assert torch.equal(last[:, 0], torch.zeros(3, 2))
    for t in range(1, 7):
        assert torch.equal(last[:, t], y[:, t - 1])
