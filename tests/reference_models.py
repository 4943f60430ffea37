"""Slow references of a learned predictor's roll-outs, used only by the tests: its k-step forecasts and its
free-run simulation by definition, one predict per step with the predictions written over a copy of the
outputs (independent of the package's fed-back inputs, mop.models.simulate.fed_back)."""

import copy

import torch

from mop.systems.base import Trajectories


def _window_mode(p):
    """A copy of the learned predictor p that predicts with the sliding window (the definition's)."""
    window = copy.copy(p)
    window.mode = "sliding"
    return window


def half_window_start(t: int, context: int) -> int:
    """The first input of the window that mode "window" predicts y_{t+1} with (output position t): 0 inside
    the context, else the latest multiple of S = C // 2 at or before t - (C - S), so the prediction reads
    the C - S to C inputs z_start..z_t."""
    stride = max(context // 2, 1)
    return 0 if t < context else stride * ((t - context + stride) // stride)


def _rows(traj, y, last: int) -> Trajectories:
    """Rows 0..last of outputs y (B, T+1, m) with traj's inputs."""
    return Trajectories(y[:, : last + 1], None if traj.u is None else traj.u[:, : last + 1])


def reference_forecast(p, traj, steps: int) -> torch.Tensor:
    """A learned predictor's k-step forecasts (B, T+1, K, m) by definition, one predict per (origin, step),
    independent of the package's roll-outs: the forecasts f[:, t, 0..j-1] are written over the outputs
    y_t..y_{t+j-1} of a copy of the data, and f[:, t, j] is the sliding-window one-step prediction at t + j
    of that copy. f[:, :, 0] is p.predict(traj) in p's own mode; NaN where t + j > T."""
    window = _window_mode(p)
    first = p.predict(traj)  # (B, T+1, m)
    B, T1, m = first.shape
    out = first.new_full((B, T1, steps, m), float("nan"))
    out[:, :, 0] = first
    for t in range(T1):
        y = traj.y.clone()
        for j in range(1, min(steps, T1 - t)):
            y[:, t + j - 1] = out[:, t, j - 1]
            out[:, t, j] = window.predict(_rows(traj, y, t + j))[:, t + j]
    return out


def reference_simulate(p, traj, context: int) -> torch.Tensor:
    """A learned predictor's free-run simulation (B, T+1-c, m) by definition, the forecast from origin c:
    y_c of a copy of the data is overwritten by p's one-step prediction in its own mode, then for
    s = c+1..T y_s by the sliding-window one-step prediction at s of that copy."""
    window = _window_mode(p)
    y = traj.y.clone()
    for s in range(context, traj.horizon + 1):
        y[:, s] = (p if s == context else window).predict(_rows(traj, y, s))[:, s]
    return y[:, context:]
