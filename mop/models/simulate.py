"""Free-run simulation of a learned model, and the two roll-outs on its own predictions that simulation and
the k-step forecast (mop.models.forecast) share.

simulate(p, traj, c) -> (B, T+1-c, m): out[:, j] predicts y_{c+j} from z_0..z_{c-1} and then the model's own
predicted outputs with the given inputs, [yhat_c, u_c], .., [yhat_{c+j-1}, u_{c+j-1}] (a forecast from origin
c). The one chooser, simulation_path, takes
- "gap" (model.forecast_mode = "gap"): one predict with y_c..y_T read as missing (gap_simulation: beyond a
  context-limited model's context, in windows of C inputs advancing by C/2);
- "stream" where stepping the model's stream cache equals its forward (a recurrent model; a transformer
  with T <= context): the cache steps once per input (streamed_rollout);
- "window" otherwise: one forward per simulated step on the last C inputs (windowed_rollout), from the
  one-step prediction of y_c in the predictor's mode (mop.models.predict), as the forecast from origin c;
  for the transformer (with no feature or the RLS / ARX feature) the same numbers by mop.models.slide,
  one new input per open window and step (window_path chooses).
All in data units; the model's normalisation is applied by the predictor (mop.models.predict).
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor

from mop.models.predict import ModelPredictor, half_windows
from mop.models.slide import slide_fast, sliding_rollout
from mop.systems.base import Trajectories


def fed_back(pred: Tensor, u: Tensor | None, t: int) -> Tensor:
    """The model input a roll-out feeds back: [pred, u_t] (B, m + k), or pred (B, m) without inputs."""
    return pred if u is None else torch.cat([pred, u[:, t]], dim=-1)


def windowed_rollout(
    p: ModelPredictor, hist: Tensor, pred: Tensor, u: Tensor | None, start: int, count: int
) -> list[Tensor]:
    """`count` predictions, each one forward on the last C inputs (all of them for a model that is not
    context-limited) of hist (B, L, m + k) followed by the fed-back [pred, u_start], [pred', u_start+1], ..;
    pred (B, m) is the prediction of y_start. Returns [yhat_{start+1}, ..] each (B, m), float64, CPU."""
    limit = p.cfg.context if p.model.context_limited else None
    preds = []
    for i in range(count):
        hist = torch.cat([hist, fed_back(pred, u, start + i)[:, None]], dim=1)
        pred = p.last_output(hist if limit is None else hist[:, -limit:])
        preds.append(pred)
    return preds


def streamed_rollout(
    p: ModelPredictor, cache: Any, pred: Tensor, u: Tensor | None, start: int, count: int
) -> list[Tensor]:
    """As windowed_rollout, but stepping the model's stream cache (which has read the history) once per
    fed-back input; call it under torch.no_grad() with the model evaluating."""
    preds = []
    for i in range(count):
        pred = p.step(fed_back(pred, u, start + i), cache)
        preds.append(pred)
    return preds


def window_path(
    p: ModelPredictor, hist: Tensor, pred: Tensor, u: Tensor | None, start: int, count: int
) -> list[Tensor]:
    """windowed_rollout's predictions, by sliding_rollout (mop.models.slide) where the model has it: the
    same numbers at the cost of one new input per window and step."""
    if not slide_fast(p.model):
        return windowed_rollout(p, hist, pred, u, start, count)
    norm = p.normalization
    z = torch.cat([hist, hist.new_zeros(hist.shape[0], count, hist.shape[-1])], dim=1)  # (B, T, m + k)
    z[:, start:, : p.cfg.output_dim] = pred[:, None]  # a stand-in in range: the roll-out's own replace it
    if u is not None:
        z[:, start:, p.cfg.output_dim :] = u[:, start : start + count]
    inputs = p.model_inputs(z)  # (B, T, d_in); its outputs after y_{c-1} are the roll-out's
    with p.evaluating():
        cpu = lambda a: None if a is None else a.to(inputs.device)  # noqa: E731
        ys = (None, None) if norm is None else (cpu(norm.y_mean), cpu(norm.y_std))
        preds = sliding_rollout(p.model, inputs, pred.to(inputs.device), start, *ys)
    return [a.cpu() for a in preds]


def rows(traj: Trajectories, last: int) -> Trajectories:
    """Steps 0..last of traj (outputs y_0..y_last, the inputs alike)."""
    return Trajectories(traj.y[:, : last + 1], None if traj.u is None else traj.u[:, : last + 1])


def simulation_path(p: ModelPredictor, horizon: int, context: int) -> str:
    """ "gap", "stream" or "window" (see the module docstring) for T = horizon and c = context."""
    if p.cfg.forecast_mode == "gap":
        return "gap"
    if context > 0 and p.streams_exactly(horizon):
        return "stream"
    return "window"


def simulate(p: ModelPredictor, traj: Trajectories, context: int) -> Tensor:
    """(B, T+1-c, m) free-run simulation from c = context (see the module docstring)."""
    path = simulation_path(p, traj.horizon, context)
    if path == "gap":
        return gap_simulation(p, traj, context)
    z = traj.model_inputs().double()  # (B, T+1, d_in) in data units
    u = None if traj.u is None else traj.u.double()
    count = traj.horizon - context
    if path == "stream":
        with torch.no_grad(), p.evaluating():
            cache = p.model.init_cache(z.shape[0])
            for t in range(context):
                pred = p.step(z[:, t], cache)  # after z_{c-1}: the prediction of y_c
            out = [pred, *streamed_rollout(p, cache, pred, u, context, count)]
    else:
        pred = p.predict(rows(traj, context))[:, context].double().cpu()  # (B, m): y_c from z_{<c}
        out = [pred, *window_path(p, z[:, :context], pred, u, context, count)]
    return torch.stack(out, dim=1).to(traj.y.dtype)


def gap_simulation(p: ModelPredictor, traj: Trajectories, context: int) -> Tensor:
    """simulate for model.forecast_mode = "gap": y_c..y_T read as missing, one predict while T <= C (the
    model's context) or the model is not context-limited. Beyond it, windows of C inputs (outputs
    y_s..y_{s+C}) start at s = 0, S, 2S, ... (S = C // 2; mop.models.predict.half_windows): each predicts
    the outputs its predecessor did not reach, reading the ones before as measured (the record's up to c,
    the simulated ones after), so every simulated output sees at least C - S steps and the cost is about
    2 T / C forwards. (B, T+1-c, m)."""
    y = traj.y.clone()
    y[:, context:] = float("nan")
    C, T = p.cfg.context, traj.horizon
    if not p.model.context_limited or T <= C:
        return p.predict(Trajectories(y, traj.u))[:, context:]
    done = 0  # y_0..y_done are measured or simulated
    for start, end in half_windows(T, C):  # the window's outputs y_start..y_end: C inputs or fewer
        u = None if traj.u is None else traj.u[:, start : end + 1]
        pred = p.predict(Trajectories(y[:, start : end + 1], u))  # (B, end - start + 1, m)
        new = max(done + 1, context)
        y[:, new : end + 1] = pred[:, new - start :].to(y)
        done = end
    return y[:, context:]
