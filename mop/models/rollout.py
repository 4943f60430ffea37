"""k-step forecasts of a learned model from every origin at once, at the cost of the new inputs only.

The forecast from origin t (mop.models.forecast) at step j >= 1 reads

    S(t, j) = z_0..z_{t-1}, n_1..n_j,      n_i = [f_{t, i-1}, u_{t+i-1}]

(z_t = [y_t, u_t] the model inputs, f_{t,0} the one-step prediction of y_t, f_{t,i} the forecast of y_{t+i})
and f_{t,j} is the model's output at the last input of S(t, j). A context-limited model (the transformer)
reads the last C inputs of S(t, j), re-positioned from 0: the paper's sliding window, window start
s = t + j - C. A recurrent model (the GRU) reads all of them. All in the model's units (normalised inputs).

Transformer (transformer_forecast):
- window 0 (z_0..z_{T0-1}, T0 = min(T, C)) is prefilled once: the one-step predictions y_1..y_T0 and
  every layer's keys and values;
- inside the context (t + j <= C, window start 0): attention is causal, so the keys and values of
  z_0..z_{t-1} are those of window 0; each origin is a branch that keeps the keys and values of its
  own new inputs, and step j costs one new input per origin;
- beyond it (t + j > C): the windows s = 1..T-C are prefilled in batches, in order of s (the last output
  only: the one-step prediction y_{s+C}; the last block skips the other positions' attention output and
  MLP), and right after its prefill window s serves step j = 1..K-1 of origin t = s + C - j. Its prefix
  z_s..z_{t-1} keeps the prefill's keys and values (positions 0..C-n-1), but the n = min(j, C) new inputs
  must be recomputed (what they attend to changed; only the last one's output is read): step j costs n
  new inputs per origin, K(K-1)/2 over a K-step forecast against C for the window's one-step prediction.
  This is what the paper's window semantics cost; a rolling KV cache (mode "stream") would be cheaper
  and not equal. The new inputs' keys and values are written into the window's buffers in place:
  step j writes positions C-n..C-1 and later steps read only positions below C-n-1.
GRU (recurrent_forecast): the hidden state after z_0..z_{t-1} is kept for every origin t (one step per
input), and all origins advance together, one GRU step per forecast step.

Both equal the definition (one forward of S(t, j) per (t, j): mop.models.forecast.windowed_forecast, and
the tests' own reference) to float rounding (tests/test_rollout.py, float64 models: 1e-10). Entries with
t + j > T are NaN.
"""

from __future__ import annotations

import torch
from torch import Tensor

from mop.errors import MopError
from mop.models.interface import LearnedModel

CACHE_BUDGET_BYTES = 256 * 2**20  # keys/values kept per chunk of systems (transformer_chunk_size)
WINDOWS_PER_BATCH = 256  # sliding windows per prefill forward and its branches (activations in cache)


def can_branch(model: LearnedModel) -> bool:
    """Whether forecast_batch has a fast path for `model`, by its declared capabilities: prefill / branch
    (the transformer) or a stream state that copies branch (the GRU).

    Not for a model that reads input features (model.input_scale / rls_order): they are functions of the
    whole window, fed-back inputs included, so its forecasts take another path."""
    return (model.supports_branch and not model.reads_features) or model.branchable_state


def forecast_batch(model: LearnedModel, z: Tensor, steps: int, first: Tensor | None = None) -> Tensor:
    """z (B, T, d_in) model inputs z_0..z_{T-1} -> f (B, T+1, K, m), K = steps, in the model's units.

    f[:, t, j] forecasts y_{t+j} from z_0..z_{t-1} (see the module docstring); NaN where t + j > T.
    first (B, T+1, m): one-step predictions to roll out from instead of the window's own (mode "stream").
    MopError for a model that can_branch refuses.
    """
    if model.supports_branch and not model.reads_features:
        return transformer_forecast(model, z, steps, first)
    if model.branchable_state:
        return recurrent_forecast(model, z, steps)
    raise MopError(f"model arch {model.cfg.arch!r} has no fast k-step forecast (see can_branch)")


def transformer_chunk_size(cfg, horizon: int, steps: int) -> int:
    """Systems per forecast_batch call: the first window's keys/values and each origin's own new ones
    (kept across all steps) within CACHE_BUDGET_BYTES; the later windows are batched by WINDOWS_PER_BATCH."""
    T0 = min(horizon, cfg.context)
    floats = 2 * cfg.num_layers * cfg.width * (T0 + T0 * max(steps - 1, 0))
    return max(1, CACHE_BUDGET_BYTES // (4 * floats))


def transformer_forecast(model: LearnedModel, z: Tensor, steps: int, first: Tensor | None = None) -> Tensor:
    """forecast_batch for a context-limited model with prefill / branch (mop.models.transformer).

    Window 0 and the origins inside the context first; then the later windows s in batches, in order of s:
    a batch's prefill, then for j = 1..K-1 the origins t = s + C - j of its windows (their inputs
    f_{t, <j} come from windows < s, or from the same batch at step j - 1, so they are ready)."""
    B, T, _ = z.shape
    C, m = model.cfg.context, model.cfg.output_dim
    T0 = min(T, C)
    f = z.new_full((B, T + 1, steps, m), float("nan"))
    mu, base = model.prefill(z[:, :T0])  # window 0: (B, T0, m), L x (B, H, T0, hd)
    f[:, 0, 0] = 0.0  # no data: the model's units (LearnedPredictor maps 0 to y_mean)
    f[:, 1 : T0 + 1, 0] = mu  # y_1..y_T0
    if first is not None:
        f[:, :, 0] = first
    inputs = z[..., m:]  # (B, T, k) the given inputs u_t (k = 0 without inputs)
    shape = (B, T0, base[0][0].shape[1], max(steps - 1, 1), base[0][0].shape[-1])  # (B, T0, H, K-1, hd)
    own = [(k.new_empty(shape), v.new_empty(shape)) for k, v in base]  # origins' n_1.., read once written
    for j in range(1, min(steps, T + 1)):
        _inside(model, f, inputs, base, own, j, T0)
    per_batch = max(1, WINDOWS_PER_BATCH // B)  # window starts per batch
    for a in range(1, T - C + 1, per_batch):
        _beyond(model, f, z, range(a, min(a + per_batch, T - C + 1)), steps, first is None)
    return f


def _inside(model, f: Tensor, inputs: Tensor, base: list, own: list, j: int, T0: int) -> None:
    """Step j of the origins t = 0..T0-j (t + j <= C): one new input n_j each, at position t + j - 1,
    attending to the first window's keys 0..t-1, its own n_1..n_{j-1} and itself."""
    O = T0 - j + 1
    if O <= 0:
        return
    t = torch.arange(O, device=f.device)
    x = _token(f[:, :O, j - 1], inputs[:, j - 1 : j - 1 + O])[:, :, None]  # (B, O, 1, d_in)
    mask = torch.arange(T0, device=f.device)[None, None, :] < t[:, None, None]  # (O, 1, T0)
    earlier = None if j == 1 else [(k[:, :O, :, : j - 1], v[:, :O, :, : j - 1]) for k, v in own]
    mu, new = model.branch(x, (t + j - 1)[:, None], base, mask, earlier)  # (B, O, 1, m)
    f[:, :O, j] = mu[:, :, 0]
    for (k, v), (k_new, v_new) in zip(own, new, strict=True):  # keep n_j's keys for step j + 1
        k[:, :O, :, j - 1], v[:, :O, :, j - 1] = k_new[..., 0, :], v_new[..., 0, :]


def _beyond(model, f: Tensor, z: Tensor, starts: range, steps: int, one_step: bool) -> None:
    """The windows s in `starts` (1 <= s <= T-C, consecutive): prefill z_s..z_{s+C-1} (one_step: its last
    output is y_{s+C}), then step j = 1..K-1 of the origins t = s + C - j: window s holds z_s..z_{t-1}
    (the prefill's positions 0..C-n-1) and the last n = min(j, C) new inputs (recomputed, positions
    C-n..C-1; only the last one's output is read)."""
    B, T, d_in = z.shape
    C, m = model.cfg.context, model.cfg.output_dim
    a, S = starts.start, len(starts)
    windows = z.unfold(1, C, 1)[:, a : a + S].transpose(-1, -2).reshape(B * S, C, d_in)
    mu, kv = model.prefill(windows, last=True)  # (B S, 1, m), L x (B S, H, C, hd)
    if one_step:
        f[:, a + C : a + C + S, 0] = mu.view(B, S, m)  # window s's last output is y_{s+C}
    cache = [(k.contiguous(), v.contiguous()) for k, v in kv]  # (B S, H, C, hd), rewritten from the end
    inputs = z[..., m:]
    for j in range(1, min(steps, T + 1)):
        lo = max(a, j - C)  # t = s + C - j >= 0
        if lo >= a + S:
            continue
        n, O, t0 = min(j, C), a + S - lo, lo + C - j  # new inputs, origins t0..t0+O-1
        y_fed = f[:, t0 : t0 + O, j - n : j]  # (B, O, n, m): f_{t, j-n..j-1}
        u_fed = inputs.unfold(1, n, 1)[:, t0 + j - n : t0 + j - n + O].transpose(-1, -2)  # (B, O, n, k)
        x = _token(y_fed, u_fed)  # (B, O, n, d_in): one window per origin, its prefix its own
        if O < S:  # j > C: the first windows have no origin t = s + C - j >= 0 (zero inputs, not read)
            x = torch.cat([x.new_zeros(B, S - O, n, d_in), x], dim=1)
        # window s at step j: positions 0..C-n-1 still hold its prefill (steps < j wrote positions > C-j)
        mu, _ = model.prefill(x.reshape(B * S, n, d_in), last=True, cache=cache, start=C - n)  # (B S, 1, m)
        f[:, t0 : t0 + O, j] = mu.view(B, S, m)[:, S - O :]


def _token(y: Tensor, u: Tensor) -> Tensor:
    """A fed-back input [yhat, u] (..., m + k): predicted outputs y (..., m), given inputs u (..., k)."""
    return y if u.shape[-1] == 0 else torch.cat([y, u], dim=-1)


def recurrent_forecast(model: LearnedModel, z: Tensor, steps: int) -> Tensor:
    """forecast_batch for a recurrent model whose cache holds its state h (L, B, d) (mop.models.gru)."""
    B, T, _ = z.shape
    m = model.cfg.output_dim
    f = z.new_full((B, T + 1, steps, m), float("nan"))
    cache = model.init_cache(B)
    states, one_step = [], []
    for t in range(T):
        states.append(cache.h)  # (L, B, d): after z_0..z_{t-1}, the state of origin t
        one_step.append(model.step(z[:, t], cache))  # (B, m): y_{t+1}
    f[:, 0, 0] = 0.0
    f[:, 1:, 0] = torch.stack(one_step, dim=1)
    h = torch.stack(states, dim=2)  # (L, B, T, d)
    L, d = h.shape[0], h.shape[-1]
    inputs = z[..., m:]
    for j in range(1, min(steps, T + 1)):
        O = T - j + 1  # origins 0..T-j
        x = _token(f[:, :O, j - 1], inputs[:, j - 1 : j - 1 + O])  # (B, O, d_in)
        cache = model.init_cache(B * O)
        cache.h = h[:, :, :O].reshape(L, B * O, d)  # every origin's state, branched
        f[:, :O, j] = model.step(x.reshape(B * O, -1), cache).view(B, O, m)
        h = cache.h.view(L, B, O, d)
    return f
