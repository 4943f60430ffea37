"""A trained model as a one-step predictor: yhat[:, 0] = 0, yhat[:, t] = model output at input position t-1.

The model reads z_t = [y_t, u_t] (traj.model_inputs()) for t = 0..T-1 and predicts y_1..y_T.
Trajectories longer than the training context C (T > C) are handled by `mode` (the one chooser here,
ModelPredictor._chunk):
- "window" (the default): half-overlapping windows (half_stride): windows of C inputs start every
  S = C // 2 steps, the first equal to the forward on z_0..z_{C-1}, each later one supplying only the
  outputs at its positions >= C - S, so yhat_{t+1} reads between C - S and C inputs, the last C - S to C of
  z_0..z_t; about 2 T / C forwards per record, linear in T.
- "sliding" (the paper's code): yhat_{t+1} reads exactly the last C inputs z_{t-C+1}..z_t; one forward per
  step (sliding_window, windows batched), so T - C + 1 forwards per record. Kept as the reference the
  default is measured against (tests, mop bench predict).
- "stream": one step at a time with the model's stream cache (see mop.models.transformer), constant cost
  per step. Equal to the others for t <= C; beyond C it is the rolling-cache approximation documented there.
For T <= C all modes equal a single forward pass. A model without a context limit (context_limited = False,
the GRU) runs the full recurrence in every mode (streaming it is exact). Every window, as the forward,
starts the model's input features afresh (a record_norm model's running moments, the RLS / ARX feature:
mop.models.features), from the window's first input, so a window is exactly the model's forward on it.
Features of the whole record so far, sliced per window (what the stream keeps), measured on
pretrained:lti-siso (16 records x 1200 steps, seeds 0 / 1; mean per-record RMSE at every 25th step beyond
the context): 0.00609 / 0.00620 against these windows' 0.00633 / 0.00704 and the sliding window's 0.00675 /
0.00724; not done here: forecasts and the gap simulation would have to carry them too.

Normalised inputs and the out-of-range warning: mop.models.normalization; yhat[:, 0] is then y_mean.

Missing outputs (NaN in traj.y): a model trained with drop-outs (model.observation_mask) reads
[y_t zero-filled, u_t, observed_t] (after normalisation) and predicts every step, gaps included. A model
without the mask refuses data with gaps in one line.
"""

from __future__ import annotations

import contextlib
import dataclasses
import warnings
from collections.abc import Callable, Iterator
from typing import Any

import torch
from torch import Tensor

from mop.errors import MopError, MopWarning
from mop.missing import masked_inputs
from mop.models.interface import LearnedModel
from mop.models.normalization import InputStats, Normalization, out_of_range
from mop.models.registry import predictor_names
from mop.pretrained import dimensions, fitting_hint
from mop.systems.base import Trajectories

MODES = ("window", "sliding", "stream")  # the paths beyond the context (see the module docstring)


class ModelPredictor:
    """A model of mop.models.build_model as a one-step predictor (run in eval mode, no grad, in chunks)."""

    def __init__(
        self,
        model: LearnedModel,
        name: str = "",
        mode: str = "window",
        chunk_size: int = 256,
        normalization: Normalization | None = None,
        source: str = "",
        input_stats: InputStats | None = None,
    ) -> None:
        if mode not in MODES:
            raise MopError(f"predictor mode must be one of {', '.join(MODES)}, got {mode!r}")
        if mode == "stream" and not model.supports_stream:
            raise MopError(f"model arch {model.cfg.arch!r} does not stream; use mode 'window'")
        if chunk_size <= 0:
            raise MopError(f"chunk_size must be positive, got {chunk_size}")
        name = name or predictor_names().get(model.cfg.arch, model.cfg.arch)  # "": its architecture's entry
        self.model, self.name, self.mode, self.chunk_size = model, name, mode, chunk_size
        self.cfg = model.cfg
        self.source = source  # the run directory or pretrained:NAME it was loaded from, for messages
        if input_stats is None and normalization is not None:
            d_in = self.cfg.input_dim
            input_stats = ([0.0] * d_in, [1.0] * d_in)  # normalised training inputs
        self.input_stats = input_stats
        self.normalization = normalization or Normalization.of_units(self.cfg)  # the family's units
        self._warned = False

    def inputs(self, traj: Trajectories) -> Tensor:
        """The model's inputs z_0..z_{T-1} (B, T, d_in) for traj, normalised, in the model's dtype."""
        z = traj.model_inputs()  # (B, T+1, m + k), NaN where y is missing
        self._check_data(traj, z.shape[-1])
        return self.model_inputs(z[:, :-1])  # (B, T, d_in): z_0..z_{T-1}

    def _check_data(self, traj: Trajectories, width: int) -> None:
        """One-line MopError unless traj's outputs, inputs and gaps are what the model was trained on."""
        mask = traj.output_dim if self.cfg.observation_mask else 0
        if width + mask != self.cfg.input_dim or traj.output_dim != self.cfg.output_dim:
            model = self.source or "the model"
            k_data = width - traj.output_dim
            k_model = dimensions(dataclasses.asdict(self.cfg))[1]
            raise MopError(
                f"the data has output_dim={traj.output_dim} and {k_data} inputs u, but {model} was trained "
                f"with output_dim={self.cfg.output_dim} and {k_model} inputs u; "
                + fitting_hint(traj.output_dim, k_data)
            )
        if not self.cfg.observation_mask and traj.observed is not None:
            raise MopError(
                f"the trajectories have {traj.num_missing} missing outputs (NaN / empty cells) but this "
                "model was trained without them; train one with train.missing_rate > 0, or fill the gaps"
            )

    def model_inputs(self, z: Tensor) -> Tensor:
        """z (B, L, m + k) in data units (NaN where y is missing) -> the model's inputs (B, L, d_in):
        normalised, then zero-filled with the observation mask appended for a model that has one."""
        if self.normalization is not None:
            z = self.normalization.inputs(z)
        self._warn_out_of_range(z)
        if self.cfg.observation_mask:
            z = masked_inputs(z, self.cfg.output_dim)
        p = next(self.model.parameters())
        return z.to(device=p.device, dtype=p.dtype)

    def _warn_out_of_range(self, z: Tensor) -> None:
        """Warn (once) when model inputs z (B, T, d_in) lie far outside the training inputs."""
        worst = None if self._warned else out_of_range(z, self.input_stats)
        if worst is not None:
            self._warned = True
            m = self.cfg.output_dim
            channel = f"y{worst[0]}" if worst[0] < m else f"u{worst[0] - m}"
            warnings.warn(
                f"the data lie far outside what {self.source or self.name} was trained on: {channel} is "
                f"{worst[1]:.3g} training standard deviations from the training mean (RMS; the training "
                "data: 1); its predictions may be poor",
                MopWarning,
                stacklevel=4,
            )

    @torch.no_grad()
    def run(self, z: Tensor, gaussian: bool) -> tuple[Tensor, Tensor | None]:
        """z (B, T, d_in) -> mean, var|None each (B, T, m) in data units, position t predicting y_{t+1}."""
        with self.evaluating():
            starts = range(0, z.shape[0], self.chunk_size)
            parts = [self._chunk(z[i : i + self.chunk_size], gaussian) for i in starts]
        mu = torch.cat([p[0] for p in parts])
        var = torch.cat([p[1] for p in parts]) if gaussian else None
        if self.normalization is not None:
            mu, var = self.normalization.outputs(mu, var)
        return mu, var

    def _chunk(self, z: Tensor, gaussian: bool) -> tuple[Tensor, Tensor | None]:
        """The path of one chunk of systems: the stream, one forward or windows (the module docstring)."""
        T, C = z.shape[1], self.cfg.context
        if self.mode == "stream" and (T > C or not self.model.context_limited):
            return stream(self.model, z, gaussian)  # a recurrent model streams its state: exact
        if not self.model.context_limited or T <= C:
            return self.model.predict_distribution(z) if gaussian else (self.model(z), None)
        if self.mode == "sliding":
            return sliding_window(self.model, z, gaussian, C, self.chunk_size)
        if not gaussian:
            return half_stride(self.model, (z,), C, self.chunk_size), None
        both = half_stride(
            lambda x: torch.cat(self.model.predict_distribution(x), -1), (z,), C, self.chunk_size
        )
        return both.split(self.cfg.output_dim, -1)  # (B, T, m) mean and var

    def _pad(self, out: Tensor, like: Tensor, fill: float, scale: Tensor | None = None) -> Tensor:
        """Prepend the data-free prediction for y_0 (fill, or `scale` (m,)): (B, T, m) -> (B, T+1, m)."""
        first = torch.full_like(out[:, :1], fill)
        if scale is not None:
            first = scale.to(first).expand_as(first)
        return torch.cat([first, out], dim=1).to(device=like.device, dtype=like.dtype)

    def predict(self, traj: Trajectories) -> Tensor:
        """(B, T+1, m): yhat[:, 0] = 0 (y_mean when normalised), yhat[:, t] from z_0..z_{t-1}."""
        mu, _ = self.run(self.inputs(traj), gaussian=False)
        norm = self.normalization
        return self._pad(mu, traj.y, 0.0, None if norm is None else norm.y_mean)

    def predict_distribution(self, traj: Trajectories) -> tuple[Tensor, Tensor]:
        """Gaussian readout: (mean, var) each (B, T+1, m); index 0 is (0, 1) by convention (no data), or
        (y_mean, y_std^2) when normalised."""
        if self.cfg.readout != "gaussian":
            raise MopError("predict_distribution needs a model with readout='gaussian'")
        mu, var = self.run(self.inputs(traj), gaussian=True)
        norm = self.normalization
        if norm is None:
            return self._pad(mu, traj.y, 0.0), self._pad(var, traj.y, 1.0)
        return self._pad(mu, traj.y, 0.0, norm.y_mean), self._pad(var, traj.y, 1.0, norm.y_std**2)

    @contextlib.contextmanager
    def evaluating(self) -> Iterator[None]:
        """The model in eval mode inside, its own mode restored after."""
        was_training = self.model.training
        self.model.eval()
        try:
            yield
        finally:
            self.model.train(was_training)

    def streams_exactly(self, horizon: int) -> bool:
        """Whether stepping the model's stream cache over T = horizon inputs equals its forward: a streaming
        model that is not context-limited always; a context-limited one while T <= its context (inside it,
        its cache and its features' running state equal the forward's, mop.models.transformer)."""
        if not self.model.supports_stream:
            return False
        return not self.model.context_limited or horizon <= self.cfg.context

    def step(self, z: Tensor, cache: Any) -> Tensor:
        """One input z (B, m + k) in data units through the model's stream cache -> its mean (B, m) in data
        units, float64 on the CPU."""
        mu = self.model.step(self.model_inputs(z[:, None])[:, 0], cache)
        if self.normalization is not None:
            mu = self.normalization.outputs(mu, None)[0]
        return mu.double().cpu()

    def last_output(self, z: Tensor) -> Tensor:
        """The model's mean output (B, m) in data units, float64, at the last position of z (B, L, m + k)."""
        mu, _ = self.run(self.model_inputs(z), gaussian=False)
        return mu[:, -1].double().cpu()


def stream(model: LearnedModel, z: Tensor, gaussian: bool = False) -> tuple[Tensor, Tensor | None]:
    """Step the model's cache over z (B, T, d_in) -> mean, var|None each (B, T, m)."""
    cache = model.init_cache(z.shape[0])
    outs = [model.step_distribution(z[:, t], cache) for t in range(z.shape[1])]  # T x ((B, m), (B, m)|None)
    mu = torch.stack([o[0] for o in outs], dim=1)
    var = torch.stack([o[1] for o in outs], dim=1) if gaussian else None
    return mu, var


def later_windows(z: Tensor, context: int) -> Tensor:
    """The windows z_{t-C+1}..z_t for t = C..T-1, system-major: z (B, T, d_in) -> (B (T-C), C, d_in)."""
    windows = z.unfold(1, context, 1)[:, 1:]  # (B, T-C+1, d_in, C) -> drop the first: (B, T-C, d_in, C)
    return windows.permute(0, 1, 3, 2).reshape(-1, context, z.shape[-1])


def sliding_window(
    model: LearnedModel, z: Tensor, gaussian: bool, context: int, windows_per_batch: int = 256
) -> tuple[Tensor, Tensor | None]:
    """The paper's sliding window: output t (t >= C) is the last output of a forward on z_{t-C+1}..z_t.

    Outputs 0..C-1 come from one forward on z_0..z_{C-1}. z (B, T, d_in) -> mean, var|None each (B, T, m).
    The later windows run with last=True (the model computes their last output only; a context-limited
    model's forward and predict_distribution take it), equal to the full forward's last output.
    """
    B, T, d_in = z.shape
    run = model.predict_distribution if gaussian else (lambda x, last=False: (model(x, last), None))
    mu0, var0 = run(z[:, :context])  # (B, C, m)
    windows = later_windows(z, context)  # (B*(T-C), C, d_in)
    mus, vars_ = [], []
    for i in range(0, windows.shape[0], windows_per_batch):
        mu, var = run(windows[i : i + windows_per_batch], last=True)  # (b, 1, m)
        mus.append(mu[:, -1])
        vars_.append(None if var is None else var[:, -1])
    mu = torch.cat([mu0, torch.cat(mus).view(B, T - context, -1)], dim=1)  # (B, T, m)
    var = torch.cat([var0, torch.cat(vars_).view(B, T - context, -1)], dim=1) if gaussian else None
    return mu, var


def half_windows(steps: int, context: int) -> list[tuple[int, int]]:
    """Half-overlapping windows over `steps` inputs: (start, end), the window's inputs z_start..z_{end-1},
    start = 0, S, 2S, .. (S = C // 2, at least 1; C = context) up to the first that reaches the last input;
    end = min(start + C, steps). Window k's outputs at positions >= its predecessor's end - start (>= C - S:
    after at least C - S of its inputs) are the ones its predecessor did not reach."""
    stride, spans = max(context // 2, 1), []
    for start in range(0, steps, stride):
        spans.append((start, min(start + context, steps)))
        if spans[-1][1] == steps:
            break
    return spans


def half_stride(
    fn: Callable[..., Tensor], inputs: tuple[Tensor, ...], context: int, windows_per_batch: int = 256
) -> Tensor:
    """fn's outputs over half_windows: inputs each (B, T, ...) cut alike into the windows (the full ones
    batched, windows_per_batch at a time), fn maps window inputs each (b, L, ...) to (b, L, ...); output
    position t (B, T, ...) is taken from the one window that supplies it (half_windows). The first window
    covers positions 0..C-1, so for T <= C this is fn on the whole of inputs."""
    B, T = inputs[0].shape[:2]
    spans = half_windows(T, context)
    full = [s for s, e in spans if e - s == context]
    windows = []  # one (B, L, ..) per span
    if full:
        cut = [torch.stack([x[:, s : s + context] for s in full], 1).flatten(0, 1) for x in inputs]
        batches = range(0, cut[0].shape[0], windows_per_batch)
        outs = torch.cat([fn(*(x[i : i + windows_per_batch] for x in cut)) for i in batches])
        windows = list(outs.unflatten(0, (B, len(full))).unbind(1))  # (B n, C, ..) -> n x (B, C, ..)
    if len(windows) < len(spans):  # the last window is shorter
        s, e = spans[-1]
        windows.append(fn(*(x[:, s:e] for x in inputs)))
    pieces, done = [], 0  # outputs 0..done-1 are taken
    for (s, e), out in zip(spans, windows, strict=True):
        pieces.append(out[:, done - s :])
        done = e
    return torch.cat(pieces, 1)  # (B, T, ..)
