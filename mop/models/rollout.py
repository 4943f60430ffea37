"""k-step forecasts of a learned model from every origin at once, at the cost of the new inputs only.

The forecast from origin t (LearnedPredictor.forecast) at step j >= 1 reads

    S(t, j) = z_0..z_{t-1}, n_1..n_j,      n_i = [f_{t, i-1}, u_{t+i-1}]

(z_t = [y_t, u_t] the model inputs, f_{t,0} the one-step prediction of y_t, f_{t,i} the forecast of y_{t+i})
and f_{t,j} is the model's output at the last input of S(t, j). A context-limited model (the transformer)
reads the last C inputs of S(t, j), re-positioned from 0: the paper's sliding window, window start
s = t + j - C. A recurrent model (the GRU) reads all of them. All in the model's units (normalised inputs).

Transformer (transformer_forecast):
- one forward ("prefill") per sliding window z_s..z_{s+T0-1} (T0 = min(T, C), s = 0..T-T0) gives the
  one-step predictions (as LearnedPredictor.predict) and every layer's keys and values;
- inside the context (t + j <= C, window start 0): attention is causal, so the keys and values of
  z_0..z_{t-1} are those of the first window; each origin is a branch that keeps the keys and values of its
  own new inputs, and step j costs one new input per origin;
- beyond it (t + j > C): the window z_s..z_{t-1}, n_1..n_j moved with j, so its prefix z_s..z_{t-1} has the
  keys and values of prefill window s (the first C - j positions), but the new inputs must be recomputed
  (what they attend to changed): step j costs min(j, C) new inputs per origin. This is what the paper's
  window semantics cost; a rolling KV cache (mode "stream") would be cheaper and not equal.
GRU (recurrent_forecast): the hidden state after z_0..z_{t-1} is kept for every origin t (one step per
input), and all origins advance together, one GRU step per forecast step.

Both equal LearnedPredictor.reference_forecast (one forward of S(t, j) per (t, j)) to float rounding
(tests/test_rollout.py, float64 models: 1e-10). Entries with t + j > T are NaN.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

CACHE_BUDGET_BYTES = 256 * 2**20  # keys/values kept per chunk of systems (transformer_chunk_size)
WINDOWS_PER_CHUNK = 2048  # sliding windows per chunk of systems
PREFILL_BATCH = 256  # windows per prefill forward (as mop.models.predictor.sliding_window)


def can_branch(model: nn.Module) -> bool:
    """Whether forecast_batch has a fast path for `model` (transformer prefill/branch, or a GRU cache)."""
    if model.context_limited:
        return callable(getattr(model, "prefill", None)) and callable(getattr(model, "branch", None))
    return callable(getattr(model, "init_cache", None)) and hasattr(model.init_cache(1), "h")


def forecast_batch(model: nn.Module, z: Tensor, steps: int, first: Tensor | None = None) -> Tensor:
    """z (B, T, d_in) model inputs z_0..z_{T-1} -> f (B, T+1, K, m), K = steps, in the model's units.

    f[:, t, j] forecasts y_{t+j} from z_0..z_{t-1} (see the module docstring); NaN where t + j > T.
    first (B, T+1, m): one-step predictions to roll out from instead of the window's own (mode "stream").
    """
    if model.context_limited:
        return transformer_forecast(model, z, steps, first)
    return recurrent_forecast(model, z, steps)


def transformer_chunk_size(cfg, horizon: int, steps: int) -> int:
    """Systems per forecast_batch call: the kept keys/values within CACHE_BUDGET_BYTES and at most
    WINDOWS_PER_CHUNK sliding windows (activations that stay in cache)."""
    T0, windows = min(horizon, cfg.context), max(horizon - cfg.context, 0) + 1
    floats = 2 * cfg.num_layers * cfg.width * (windows * T0 + T0 * max(steps - 1, 0))
    return max(1, min(CACHE_BUDGET_BYTES // (4 * floats), WINDOWS_PER_CHUNK // windows))


def transformer_forecast(model: nn.Module, z: Tensor, steps: int, first: Tensor | None = None) -> Tensor:
    """forecast_batch for a context-limited model with prefill / branch (mop.models.transformer)."""
    B, T, _ = z.shape
    C, m = model.cfg.context, model.cfg.output_dim
    T0 = min(T, C)
    f = z.new_full((B, T + 1, steps, m), float("nan"))
    mu, base = model.prefill(z[:, :T0])  # window 0: (B, T0, m), L x (B, H, T0, hd)
    f[:, 0, 0] = 0.0  # no data: the model's units (LearnedPredictor maps 0 to y_mean)
    f[:, 1 : T0 + 1, 0] = mu  # y_1..y_T0
    mu, windows = _prefill_windows(model, z)  # windows s = 1..T-C: (B, T-C, m), L x (B, T-C, H, C, hd)
    f[:, T0 + 1 :, 0] = mu  # window s's last output is y_{s+C}
    if first is not None:
        f[:, :, 0] = first
    inputs = z[..., m:]  # (B, T, k) the given inputs u_t (k = 0 without inputs)
    shape = (B, T0, base[0][0].shape[1], max(steps - 1, 1), base[0][0].shape[-1])  # (B, T0, H, K-1, hd)
    own = [(k.new_zeros(shape), v.new_zeros(shape)) for k, v in base]  # each origin's n_1.. per layer
    for j in range(1, min(steps, T + 1)):
        _inside(model, f, inputs, base, own, j, T0)
        _beyond(model, f, inputs, windows, j, T)
    return f


def _prefill_windows(model: nn.Module, z: Tensor) -> tuple[Tensor, list[tuple[Tensor, Tensor]]]:
    """The sliding windows z_s..z_{s+C-1}, s = 1..T-C, prefilled PREFILL_BATCH at a time: their last output
    (B, T-C, m) and every layer's keys, values (B, T-C, H, C, hd)."""
    B, T, d_in = z.shape
    C, L, H = model.cfg.context, model.cfg.num_layers, model.cfg.num_heads
    S = max(T - C, 0)
    windows = z.unfold(1, C, 1)[:, 1:].transpose(-1, -2).reshape(B * S, C, d_in) if S else z[:0, :C]
    mu = z.new_empty(B * S, model.cfg.output_dim)
    kv = [tuple(z.new_empty(B * S, H, C, model.cfg.width // H) for _ in range(2)) for _ in range(L)]
    for i in range(0, B * S, PREFILL_BATCH):
        out, layers = model.prefill(windows[i : i + PREFILL_BATCH])  # (b, C, m), L x (b, H, C, hd)
        mu[i : i + PREFILL_BATCH] = out[:, -1]
        for (k, v), (k_new, v_new) in zip(kv, layers, strict=True):
            k[i : i + PREFILL_BATCH], v[i : i + PREFILL_BATCH] = k_new, v_new
    return mu.view(B, S, model.cfg.output_dim), [
        (k.view(B, S, *k.shape[1:]), v.view(B, S, *v.shape[1:])) for k, v in kv
    ]


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


def _beyond(model, f: Tensor, inputs: Tensor, windows: list, j: int, T: int) -> None:
    """Step j of the origins t with C < t + j <= T: window s = t + j - C holds z_s..z_{t-1} (prefill window
    s, positions 0..C-n-1) and the last n = min(j, C) new inputs (recomputed, positions C-n..C-1)."""
    C = model.cfg.context
    lo, hi = max(0, C - j + 1), T - j  # origins
    if hi < lo:
        return
    n = min(j, C)
    P = C - n  # prefix length; when P > 0 the origins lo..hi use windows s = 1..T-C, all of them
    y_fed = f[:, lo : hi + 1, j - n : j]  # (B, O, n, m): f_{t, j-n..j-1}
    u_fed = inputs.unfold(1, n, 1)[:, lo + j - n : hi + j - n + 1].transpose(-1, -2)  # (B, O, n, k)
    x = _token(y_fed, u_fed)  # (B, O, n, d_in): one branch per origin, its prefix its own
    positions = torch.arange(P, C, device=f.device)[None]  # (1, n)
    prefix = None if P == 0 else [(k[..., :P, :], v[..., :P, :]) for k, v in windows]  # (B, O, H, P, hd)
    mu, _ = model.branch(x, positions, None, None, prefix)  # (B, O, n, m)
    f[:, lo : hi + 1, j] = mu[:, :, -1]


def _token(y: Tensor, u: Tensor) -> Tensor:
    """A fed-back input [yhat, u] (..., m + k): predicted outputs y (..., m), given inputs u (..., k)."""
    return y if u.shape[-1] == 0 else torch.cat([y, u], dim=-1)


def recurrent_forecast(model: nn.Module, z: Tensor, steps: int) -> Tensor:
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
