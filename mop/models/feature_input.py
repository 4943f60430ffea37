"""A network that reads its least-squares feature's free run as an input and predicts what it leaves.

With data.feature_input = "free-run" (the records recipe's default network, mop.recipe.plan), a records
run holds a fitted least-squares model beside its network (RUN/feature/fitted.json: the cubic NARX or ARX
the recipe chooses on the training part, mop.identify.narx_model) and the network is trained on, and
predicts, each record with that model's run as m more input channels:

    s_t = the feature's one-step prediction of y_t from y_<t      t < c
    s_t = the feature's free run from y_<c and u_<t               t >= c
    the network reads y_t - s_t as its outputs and (u_t, s_t) as its inputs; yhat_t = s_t + its prediction

c is the number of measured outputs a simulation starts from (the test's initialisation window); each
record trained on is read so from its first n outputs (n: the held-out check's window,
mop.recipe.selection.init_window, kept in the feature's file as INIT_KEY), which one-step predictions and
forecasts use too. So in a free run the network corrects a whole simulation of the feature rather than
rebuilding the plant from its inputs: on the Silverbox multisine test the cubic NARX simulates at 0.90 mV
and the deep LRU alone at 1.29; reading the NARX's run, the deep LRU simulates at 0.37 mV
(docs/results/benchmarks.md). The feature's channel before c never reads
y_t itself, so no output leaks into its own prediction.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import Tensor

from mop.identify.narx_model import FittedNARX
from mop.models.predictor import LearnedPredictor
from mop.record import Record
from mop.systems.base import Trajectories

FEATURE_DIR = (
    "feature"  # RUN/feature/fitted.json: a records run's least-squares feature, a fitted model of its own
)
INIT_KEY = "channel_init"  # in that file: the measured outputs each trained record's feature run started from


def feature_channel(feature: FittedNARX, traj: Trajectories, context: int) -> Tensor:
    """s (B, T+1, m), in traj.y's dtype: the feature's one-step predictions of y_0..y_{c-1} from the
    outputs before each, then its free run y_c..y_T from y_<c and the inputs (c = context, 1 <= c <= T).
    Reads no output at or after c."""
    c = max(int(context), 1)
    first = Trajectories(traj.y[:, :c], None if traj.u is None else traj.u[:, :c])
    return torch.cat([feature.predict(first), feature.simulate(traj, c)], dim=1)


def with_channel(traj: Trajectories, channel: Tensor) -> Trajectories:
    """traj as the network reads it: outputs y - s, inputs (u, s) (B, T+1, k + m)."""
    u = channel if traj.u is None else torch.cat([traj.u, channel.to(traj.u.dtype)], dim=-1)
    return Trajectories(traj.y - channel, u)


def record_with_channel(feature: FittedNARX, record: Record, context: int) -> Record:
    """A record as the network trains on it (with_channel, float64), the feature's run from its first
    `context` outputs (clipped to the record's length)."""
    y = torch.from_numpy(np.asarray(record.y, dtype=np.float64))[None]
    u = None if record.u is None else torch.from_numpy(np.asarray(record.u, dtype=np.float64))[None]
    traj = Trajectories(y, u)
    shown = with_channel(traj, feature_channel(feature, traj, min(context, len(record) - 1)))
    return Record(
        y=shown.y[0].numpy(),
        u=shown.u[0].numpy(),
        name=record.name,
        sampling_time=record.sampling_time,
        init_window=record.init_window,
    )


class FeatureInputPredictor:
    """A run of data.feature_input = "free-run" as a Predictor over the records' own channels (see the
    module docstring): simulate(traj, c) runs the feature from y_<c, the network (a LearnedPredictor) on
    with_channel, and adds the two. predict and forecast read the feature's run from min(init, T) measured
    outputs (init: the window the run trained with), as each trained record did. The network's attributes
    (model, cfg, name, ...) read through, and cfg is set on it (mop.runs.with_reading)."""

    def __init__(self, network: LearnedPredictor, feature: FittedNARX, init: int) -> None:
        self.__dict__.update(network=network, feature=feature, init=int(init))

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__") or "network" not in self.__dict__:
            raise AttributeError(name)
        return getattr(self.__dict__["network"], name)

    def __setattr__(self, name: str, value: Any) -> None:
        setattr(self.network, name, value)  # cfg, model, ...: the network's

    @property
    def record_dims(self) -> tuple[int, int]:
        """(m, k): the outputs and inputs of the records it reads (its network reads k + m inputs)."""
        return self.feature.output_dim, self.feature.input_dim

    def _shown(self, traj: Trajectories, context: int) -> tuple[Trajectories, Tensor]:
        channel = feature_channel(self.feature, traj, context)
        return with_channel(traj, channel), channel

    def simulate(self, traj: Trajectories, context: int) -> Tensor:
        """(B, T+1-c, m): the feature's free run from y_<c plus the network's simulation of its residual."""
        shown, channel = self._shown(traj, context)
        return self.network.simulate(shown, context) + channel[:, max(context, 1) :].to(traj.y.dtype)

    def predict(self, traj: Trajectories) -> Tensor:
        shown, channel = self._shown(traj, min(self.init, traj.horizon))
        return self.network.predict(shown) + channel

    def predict_distribution(self, traj: Trajectories) -> tuple[Tensor, Tensor]:
        shown, channel = self._shown(traj, min(self.init, traj.horizon))
        mean, var = self.network.predict_distribution(shown)
        return mean + channel, var

    def forecast(self, traj: Trajectories, steps: int) -> Tensor:
        """(B, T+1, K, m): [:, t, j] = s_{t+j} + the network's forecast of its residual (NaN past T)."""
        shown, channel = self._shown(traj, min(self.init, traj.horizon))
        f = self.network.forecast(shown, steps)
        B, T1, m = channel.shape
        padded = torch.cat([channel, channel.new_full((B, steps, m), float("nan"))], dim=1)
        later = torch.stack([padded[:, j : j + T1] for j in range(steps)], dim=2)  # [:, t, j]: s_{t+j}
        return f + later.to(f.dtype)
