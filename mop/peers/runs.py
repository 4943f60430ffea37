"""The free run every peer gives under mop's protocol: each record simulated from its last `lags` measured
outputs before the context's end and its inputs (mop.peers.narx, mop.peers.subnet)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
from torch import Tensor

from mop.errors import MopError
from mop.systems.base import Trajectories


def free_runs(
    traj: Trajectories,
    context: int,
    lags: int,
    who: str,
    reads: str,
    run: Callable[[np.ndarray, np.ndarray], np.ndarray],
) -> Tensor:
    """(B, T+1-c, m) in traj's dtype: run(y, u) for each record of traj, with y (L, m) its outputs and u
    (L, k) its inputs from step c - lags on (c = context: the first `lags` outputs are measured, the rest
    are not to be read); run returns the L - lags simulated outputs y_c..y_T. MopError without inputs, or
    where the context holds fewer than `lags` outputs (`reads`: what the peer does with them, for the
    message)."""
    if traj.u is None:
        raise MopError(f"the {who} peer simulates from inputs: give records with inputs")
    if context < lags:
        raise MopError(f"the {who} peer {reads} from {lags} measured outputs; give n >= {lags}")
    ys, us = traj.y.double().numpy(), traj.u.double().numpy()
    out = [run(y[context - lags :], u[context - lags :]) for y, u in zip(ys, us, strict=True)]
    return torch.from_numpy(np.stack(out)).to(traj.y.dtype)
