"""k-step forecasts of a learned model: f (B, T+1, K, m), f[:, t, j] forecasts y_{t+j} from y_0..y_{t-1}.

j = 0 is the one-step predict(traj). Entries with t + j > T are NaN. The one chooser, forecast_path, takes
by model.forecast_mode and the model's declared capabilities (mop.models.interface):
- "gap" (forecast_mode "gap", a model with an observation mask): the future outputs are read as missing,
  the future inputs as given; nothing predicted is fed back (gap_forecast).
- "direct" (forecast_mode "direct"): the model's k-step heads (direct_forecast).
- forecast_mode "rollout" rolls out autoregressively on the model's own predictions: for j >= 1 the model
  reads z_0..z_{t-1} followed by [yhat_t, u_t], ..., [yhat_{t+j-1}, u_{t+j-1}] (the given future inputs,
  the predicted outputs) and yhat_{t+j} is its output at the last position, with the window semantics of
  predict: a context-limited model sees the last C of those inputs, a recurrent one all of them. A Gaussian
  read-out feeds back its mean only (no sampling), so the forecast is the mean path. Three paths, equal to
  float rounding:
  - "branch": all origins advance together at the cost of the new inputs (mop.models.rollout), for a model
    that branches (prefill / branch without input features, or a branchable stream state); beyond the
    context in modes "window" and "stream" j = 0 is the mode's one-step prediction (mop.models.predict)
    and the roll-out starts from it;
  - "stream": where stepping the stream cache equals the forward, one trunk steps over z_0..z_{T-1} and at
    each origin a copy of it steps the K-1 fed-back inputs (streamed_forecast);
  - "window": one forward per (origin, step) (windowed_forecast; a transformer with input features beyond
    its context).
"""

from __future__ import annotations

import copy

import torch
from torch import Tensor

from mop.errors import MopError
from mop.models.horizons import own_future_inputs
from mop.models.predict import ModelPredictor, half_stride, half_windows, later_windows
from mop.models.rollout import can_branch, forecast_batch, transformer_chunk_size
from mop.models.simulate import streamed_rollout, windowed_rollout
from mop.systems.base import Trajectories

GAP_ORIGINS = 8  # forecast origins per batched predict in gap_forecast


def forecast_path(p: ModelPredictor, horizon: int) -> str:
    """ "gap", "direct", "branch", "stream" or "window" (see the module docstring) for T = horizon."""
    if p.cfg.forecast_mode in ("gap", "direct"):
        return p.cfg.forecast_mode
    if can_branch(p.model):
        return "branch"
    if p.streams_exactly(horizon):
        return "stream"
    return "window"


def forecast(p: ModelPredictor, traj: Trajectories, steps: int) -> Tensor:
    """(B, T+1, K, m) k-step forecasts, K = steps, by the path forecast_path chooses."""
    paths = {
        "gap": gap_forecast,
        "direct": direct_forecast,
        "branch": branched_forecast,
        "stream": streamed_forecast,
        "window": windowed_forecast,
    }
    return paths[forecast_path(p, traj.horizon)](p, traj, steps)


def branched_forecast(p: ModelPredictor, traj: Trajectories, steps: int) -> Tensor:
    """All origins at once through mop.models.rollout.forecast_batch, in chunks of systems."""
    z = p.inputs(traj)  # (B, T, d_in) normalised, model dtype
    first = None
    if p.mode != "sliding" and p.model.context_limited and z.shape[1] > p.cfg.context:
        first = p.predict(traj).double()  # (B, T+1, m) the mode's one-step predictions
        if p.normalization is not None:
            first = p.normalization.output_units(first)
        first = first.to(z)
    chunk = p.chunk_size
    if p.model.context_limited:
        chunk = min(chunk, transformer_chunk_size(p.cfg, z.shape[1], steps))
    parts = []
    with torch.no_grad(), p.evaluating():
        for i in range(0, z.shape[0], chunk):
            part = None if first is None else first[i : i + chunk]
            parts.append(forecast_batch(p.model, z[i : i + chunk], steps, part))
    f = torch.cat(parts)  # (B, T+1, K, m) in the model's units
    if p.normalization is not None:
        f = p.normalization.outputs(f, None)[0]
    return f.to(device=traj.y.device, dtype=traj.y.dtype)


def _one_step_first(p: ModelPredictor, traj: Trajectories, steps: int) -> tuple[Tensor, Tensor]:
    """predict(traj) (B, T+1, m) and the forecast (B, T+1, K, m) holding it at j = 0, NaN elsewhere."""
    yhat = p.predict(traj)  # (B, T+1, m)
    B, T1, m = yhat.shape
    out = yhat.new_full((B, T1, steps, m), float("nan"))
    out[:, :, 0] = yhat
    return yhat, out


def streamed_forecast(p: ModelPredictor, traj: Trajectories, steps: int) -> Tensor:
    """One trunk steps the stream cache over z_0..z_{T-1}; at each origin t a copy of it steps the K-1
    fed-back inputs: T + T (K-1) single steps instead of T (K-1) forwards of up to C inputs."""
    yhat, out = _one_step_first(p, traj, steps)
    T1 = yhat.shape[1]
    z = traj.model_inputs().double()  # (B, T+1, d_in) in data units
    u = None if traj.u is None else traj.u.double()
    with torch.no_grad(), p.evaluating():
        trunk = p.model.init_cache(yhat.shape[0])
        for t in range(T1 - 1):  # the trunk has read z_0..z_{t-1}
            if steps > 1:
                branch, pred = copy.deepcopy(trunk), yhat[:, t].double().cpu()
                preds = streamed_rollout(p, branch, pred, u, t, min(steps, T1 - t) - 1)
                for j, pred in enumerate(preds, start=1):
                    out[:, t, j] = pred.to(out)
            p.step(z[:, t], trunk)
    return out


def windowed_forecast(p: ModelPredictor, traj: Trajectories, steps: int) -> Tensor:
    """One forward of the model per (origin t, step j), on the last C inputs of z_0..z_{t-1}, [yhat_t, u_t],
    .., [yhat_{t+j-1}, u_{t+j-1}]: the path of a model that neither branches nor streams exactly."""
    yhat, out = _one_step_first(p, traj, steps)
    T1 = yhat.shape[1]
    z = traj.model_inputs().double()  # (B, T+1, d_in) in data units
    u = None if traj.u is None else traj.u.double()
    for t in range(T1 - 1):
        preds = windowed_rollout(p, z[:, :t], yhat[:, t].double(), u, t, min(steps, T1 - t) - 1)
        for j, pred in enumerate(preds, start=1):
            out[:, t, j] = pred.to(out.dtype)
    return out


def gap_forecast(p: ModelPredictor, traj: Trajectories, steps: int) -> Tensor:
    """Forecasts of a model with an observation mask (model.forecast_mode = "gap"): the future outputs are
    read as missing, the future inputs as given.

    f[:, t, j] = predict(traj with y_t..y_{t+j-1} missing)[:, t + j], i.e. the model's prediction of
    y_{t+j} from y_0..y_{t-1} (and their gaps) and u_0..u_{t+j-1}, with the window semantics of predict.
    Nothing predicted is fed back, so errors do not compound through the inputs; a model trained with
    bursts of dropped outputs that are still scored (train.score_dropped) learns exactly this (a
    multi-step loss). Origins are batched in groups of GAP_ORIGINS, each cut to the rows it reads; beyond
    the context in mode "window" also to the window of predict that supplies the targets (_gap_spans), so
    the cost is about T + K T / (C / 2) forwards of at most C inputs per record, linear in T.
    """
    B, T1, m = traj.y.shape
    out = traj.y.new_full((B, T1, steps, m), float("nan"))
    for start, stop, first in _gap_spans(p, T1 - 1):
        origins = range(max(first - steps + 1, 0), stop)  # those with a target y_t..y_{t+K-1} in the span
        for g in range(origins.start, origins.stop, GAP_ORIGINS):
            group = range(g, min(g + GAP_ORIGINS, stop))
            rows = min(group[-1] + steps, stop)  # the last origin reads up to row group[-1] + K - 1
            y = traj.y[:, start:rows].repeat(len(group), 1, 1)  # (G*B, rows - start, m), origin-major
            for i, t in enumerate(group):
                y[i * B : (i + 1) * B, max(t - start, 0) : max(t + steps - 1 - start, 0)] = float("nan")
            u = None if traj.u is None else traj.u[:, start:rows].repeat(len(group), 1, 1)
            yhat = p.predict(Trajectories(y, u)).view(len(group), B, rows - start, m)
            for i, t in enumerate(group):
                for target in range(max(t, first), min(t + steps, rows)):
                    out[:, t, target - t] = yhat[i, :, target - start]
    return out


def _gap_spans(p: ModelPredictor, horizon: int) -> list[tuple[int, int, int]]:
    """(start, stop, first): rows y_start..y_{stop-1} that one predict reads, supplying the targets
    y_first..y_{stop-1}; the whole record, or beyond a context-limited model's context in mode "window" the
    half-overlapping windows of predict (mop.models.predict.half_windows), each a single forward."""
    if p.mode != "window" or not p.model.context_limited or horizon <= p.cfg.context:
        return [(0, horizon + 1, 0)]
    spans, first = [], 0
    for start, end in half_windows(horizon, p.cfg.context):  # inputs z_start..z_{end-1}: targets to y_end
        spans.append((start, end + 1, first))
        first = end + 1
    return spans


def direct_forecast(p: ModelPredictor, traj: Trajectories, steps: int) -> Tensor:
    """Forecasts read from the model's k-step heads (model.forecast_mode = "direct", model.horizons >= K):
    f[:, t, j] is head j+1 at the last input of z_0..z_{t-1}, the model's mean of y_{t+j} (j = 0 is
    predict(traj) in modes "window" and "sliding"). One forward per window, with the window semantics of
    predict (_heads); nothing is fed back. f[:, 0, j] is the data-free prediction (0, or y_mean when
    normalised); entries with t + j > T are NaN.
    """
    if not p.model.has_direct_heads:
        raise MopError(f"model arch {p.cfg.arch!r} has no k-step heads; use model.forecast_mode='rollout'")
    if steps > p.cfg.horizons:
        raise MopError(
            f"this model has {p.cfg.horizons} forecast heads (model.horizons), so it forecasts at "
            f"most {p.cfg.horizons} steps, not {steps}; ask for fewer steps or train with "
            f"model.horizons={steps}"
        )
    z = p.inputs(traj)  # (B, T, d_in)
    with torch.no_grad(), p.evaluating():
        starts = range(0, z.shape[0], p.chunk_size)
        parts = [_heads(p, z[i : i + p.chunk_size])[:, :, :steps] for i in starts]
    heads = torch.cat(parts)  # (B, T, K, m): position t - 1 forecasts y_t .. y_{t+K-1}
    if p.normalization is not None:
        heads = p.normalization.outputs(heads, None)[0]
    B, T1, m = traj.y.shape
    out = traj.y.new_full((B, T1, steps, m), float("nan"))
    out[:, 0] = 0.0 if p.normalization is None else p.normalization.y_mean.to(out)  # no data
    out[:, 1:] = heads.to(out)
    for j in range(1, steps):  # y_{t+j} beyond y_T does not exist
        out[:, T1 - j :, j] = float("nan")
    return out


def _heads(p: ModelPredictor, z: Tensor) -> Tensor:
    """z (B, T, d_in) -> the k-step heads (B, T, K, m) with the window semantics of predict: beyond the
    context, position t reads the window of mode "window" (half_stride) or, in mode "sliding",
    z_{t-C+1}..z_t; every head its future inputs u_{t+1}.. from z."""
    B, T, _ = z.shape
    C, m, K = p.cfg.context, p.cfg.output_dim, p.cfg.horizons
    model = p.model
    if not model.context_limited or T <= C:
        return model.forecast_heads(z)  # the future inputs are z's own, shifted
    future = own_future_inputs(z, p.cfg)  # (B, T, K-1, k)
    if p.mode != "sliding":
        return half_stride(lambda x, f: model.forecast_heads(x, future=f), (z, future), C, p.chunk_size)
    first = model.forecast_heads(z[:, :C], future=future[:, :C])  # (B, C, K, m)
    windows = later_windows(z, C)  # (B (T-C), C, d_in)
    later = future[:, C:].reshape(B * (T - C), 1, *future.shape[2:])  # (B (T-C), 1, K-1, k)
    step = p.chunk_size
    parts = [
        model.forecast_heads(windows[i : i + step], True, later[i : i + step])[:, -1]
        for i in range(0, windows.shape[0], step)
    ]  # each (b, K, m)
    return torch.cat([first, torch.cat(parts).view(B, T - C, K, m)], dim=1)
