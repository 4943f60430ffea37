"""The trained model as a Predictor: yhat[:, 0] = 0 and yhat[:, t] = model output at input position t-1.

The model reads z_t = [y_t, u_t] (traj.model_inputs()) for t = 0..T-1 and predicts y_1..y_T.
Trajectories longer than the training context C (T > C) are handled by `mode`:
- "window" (the paper's code): yhat_t uses the last C inputs z_{t-C}..z_{t-1}; one forward per window,
  windows batched.
- "stream": one step at a time with the model's key-value cache (see mop.models.transformer), constant cost
  per step. Equal to "window" for t <= C; beyond C it is the rolling-cache approximation documented there.
For T <= C both modes equal a single forward pass. A model without a context limit (context_limited = False,
the GRU) runs the full recurrence in both modes (streaming it is exact).

Inputs far outside what the model was trained on are flagged (once per predictor) with a MopWarning: the
root-mean-square of each input channel, in standard deviations of the training inputs from their mean
(`input_stats`, the run's inputs.json; after the normalisation of a recorded-data run, whose training inputs
have mean 0 and std 1), above OOD_RMS = 5. Training data scores 1 by construction. Measured on the outputs
of 1000 systems (T = 50) against a linear-family training set: the noise-shift experiment's largest test
noise (5x the training variance) 2.1, colored noise 2.7, upper-triangular systems 4.0 (all below, no
warning: shifts the experiments study on purpose); a 20000-step random walk is far above.

A model trained on recorded data (`mop train --data`) reads normalised inputs: `normalization` maps
z -> (z - z_mean) / z_std before the model (in float64) and the model's mean mu -> mu * y_std + y_mean
(variance var * y_std^2) after it, so predictions are in the data's units; yhat[:, 0] is then y_mean.

Missing outputs (NaN in traj.y): a model trained with drop-outs (model.observation_mask) reads
[y_t zero-filled, u_t, observed_t] (after normalisation) and predicts every step, gaps included; forecasts
feed back its own predictions as measured. A model without the mask refuses data with gaps in one line.
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import warnings
from collections.abc import Sequence

import torch
from torch import Tensor, nn

from mop.errors import MopError, MopWarning
from mop.missing import masked_inputs
from mop.models.horizons import own_future_inputs
from mop.models.registry import predictor_names
from mop.models.rollout import can_branch, forecast_batch, transformer_chunk_size
from mop.systems.base import Trajectories

GAP_ORIGINS = 8  # forecast origins per batched predict in gap_forecast
OOD_RMS = 5.0  # warn when an input channel's RMS z-score against the training inputs exceeds this


@dataclasses.dataclass(frozen=True)
class Normalization:
    """Per-channel affine scaling, float64: y_mean, y_std (m,) of outputs, u_mean, u_std (k,) of inputs."""

    y_mean: Tensor
    y_std: Tensor
    u_mean: Tensor
    u_std: Tensor

    @classmethod
    def from_lists(
        cls, y_mean: Sequence[float], y_std: Sequence[float], u_mean: Sequence[float], u_std: Sequence[float]
    ) -> Normalization:
        t = lambda v: torch.tensor(list(v), dtype=torch.float64)  # noqa: E731
        return cls(t(y_mean), t(y_std), t(u_mean), t(u_std))

    def inputs(self, z: Tensor) -> Tensor:
        """z (B, T, m + k) in data units -> normalised, float64."""
        mean = torch.cat([self.y_mean, self.u_mean]).to(z.device)
        std = torch.cat([self.y_std, self.u_std]).to(z.device)
        return (z.double() - mean) / std

    def outputs(self, mu: Tensor, var: Tensor | None) -> tuple[Tensor, Tensor | None]:
        """Normalised mean, var|None (B, T, m) -> data units, float64."""
        mean, std = self.y_mean.to(mu.device), self.y_std.to(mu.device)
        return mu.double() * std + mean, None if var is None else var.double() * std**2


class LearnedPredictor:
    """Predictor protocol around a model of mop.models.build_model (run in eval mode, no grad, in chunks)."""

    def __init__(
        self,
        model: nn.Module,
        name: str = "",
        mode: str = "window",
        chunk_size: int = 256,
        normalization: Normalization | None = None,
        source: str = "",
        input_stats: tuple[Sequence[float], Sequence[float]] | None = None,
    ) -> None:
        if mode not in ("window", "stream"):
            raise MopError(f"predictor mode must be 'window' or 'stream', got {mode!r}")
        if chunk_size <= 0:
            raise MopError(f"chunk_size must be positive, got {chunk_size}")
        name = name or predictor_names().get(model.cfg.arch, model.cfg.arch)  # "": its architecture's entry
        self.model, self.name, self.mode, self.chunk_size = model, name, mode, chunk_size
        self.cfg = model.cfg
        self.normalization = normalization
        self.source = source  # the run directory or pretrained:NAME it was loaded from, for messages
        if input_stats is None and normalization is not None:
            d_in = self.cfg.input_dim
            input_stats = ([0.0] * d_in, [1.0] * d_in)  # normalised training inputs
        self.input_stats = input_stats
        self._warned = False

    def _inputs(self, traj: Trajectories) -> Tensor:
        z = traj.model_inputs()  # (B, T+1, m + k), NaN where y is missing
        mask = traj.output_dim if self.cfg.observation_mask else 0
        width = z.shape[-1] + mask
        if width != self.cfg.input_dim or traj.output_dim != self.cfg.output_dim:
            model = self.source or "the model"
            k_data = z.shape[-1] - traj.output_dim
            k_model = self.cfg.input_dim - self.cfg.output_dim - (self.cfg.output_dim if mask else 0)
            raise MopError(
                f"the data has output_dim={traj.output_dim} and {k_data} inputs u, but {model} was trained "
                f"with output_dim={self.cfg.output_dim} and {k_model} inputs u; use a model trained on data "
                "like yours"
            )
        if not self.cfg.observation_mask and traj.observed is not None:
            raise MopError(
                f"the trajectories have {traj.num_missing} missing outputs (NaN / empty cells) but this "
                "model was trained without them; train one with train.missing_rate > 0, or fill the gaps"
            )
        return self._model_inputs(z[:, :-1])  # (B, T, d_in): z_0..z_{T-1}

    def _model_inputs(self, z: Tensor) -> Tensor:
        """z (B, L, m + k) in data units (NaN where y is missing) -> the model's inputs (B, L, d_in):
        normalised, then zero-filled with the observation mask appended for a model that has one."""
        if self.normalization is not None:
            z = self.normalization.inputs(z)
        self._check_distribution(z)
        if self.cfg.observation_mask:
            z = masked_inputs(z, self.cfg.output_dim)
        p = next(self.model.parameters())
        return z.to(device=p.device, dtype=p.dtype)

    def _check_distribution(self, z: Tensor) -> None:
        """Warn (once) when model inputs z (B, T, d_in) lie far outside the training inputs."""
        if self.input_stats is None or self._warned or z.numel() == 0:
            return
        mean, std = (torch.tensor(v, dtype=torch.float64, device=z.device) for v in self.input_stats)
        if mean.shape[0] != z.shape[-1]:
            return
        rms = (((z.double() - mean) / std) ** 2).mean(dim=(0, 1)).sqrt()  # (d_in,)
        worst = int(rms.argmax())
        if float(rms[worst]) > OOD_RMS:
            self._warned = True
            warnings.warn(
                f"the inputs lie far outside the training data of predictor {self.name!r} (input channel "
                f"{worst} has an RMS of {float(rms[worst]):.3g} training standard deviations from the "
                f"training mean; training data: 1); its predictions may be poor",
                MopWarning,
                stacklevel=3,
            )

    @torch.no_grad()
    def _run(self, z: Tensor, gaussian: bool) -> tuple[Tensor, Tensor | None]:
        """z (B, T, d_in) -> mean, var|None each (B, T, m), position t predicting y_{t+1}."""
        was_training = self.model.training
        self.model.eval()
        try:
            starts = range(0, z.shape[0], self.chunk_size)
            parts = [self._chunk(z[i : i + self.chunk_size], gaussian) for i in starts]
        finally:
            self.model.train(was_training)
        mu = torch.cat([p[0] for p in parts])
        var = torch.cat([p[1] for p in parts]) if gaussian else None
        if self.normalization is not None:
            mu, var = self.normalization.outputs(mu, var)
        return mu, var

    def _full(self, z: Tensor, gaussian: bool) -> tuple[Tensor, Tensor | None]:
        if gaussian:
            return self.model.predict_distribution(z)
        return self.model(z), None

    def _chunk(self, z: Tensor, gaussian: bool) -> tuple[Tensor, Tensor | None]:
        T, C = z.shape[1], self.cfg.context
        if self.mode == "stream" and (T > C or not self.model.context_limited):
            return stream(self.model, z, gaussian)  # a recurrent model streams its state: exact
        if not self.model.context_limited or T <= C:
            return self._full(z, gaussian)
        return sliding_window(self.model, z, gaussian, C, self.chunk_size)

    def _pad(self, out: Tensor, like: Tensor, fill: float, scale: Tensor | None = None) -> Tensor:
        """Prepend the data-free prediction for y_0 (fill, or `scale` (m,)): (B, T, m) -> (B, T+1, m)."""
        first = torch.full_like(out[:, :1], fill)
        if scale is not None:
            first = scale.to(first).expand_as(first)
        return torch.cat([first, out], dim=1).to(device=like.device, dtype=like.dtype)

    def predict(self, traj: Trajectories) -> Tensor:
        """(B, T+1, m): yhat[:, 0] = 0 (y_mean when normalised), yhat[:, t] from z_0..z_{t-1}."""
        mu, _ = self._run(self._inputs(traj), gaussian=False)
        norm = self.normalization
        return self._pad(mu, traj.y, 0.0, None if norm is None else norm.y_mean)

    def predict_distribution(self, traj: Trajectories) -> tuple[Tensor, Tensor]:
        """Gaussian readout: (mean, var) each (B, T+1, m); index 0 is (0, 1) by convention (no data), or
        (y_mean, y_std^2) when normalised."""
        if self.cfg.readout != "gaussian":
            raise MopError("predict_distribution needs a model with readout='gaussian'")
        mu, var = self._run(self._inputs(traj), gaussian=True)
        norm = self.normalization
        if norm is None:
            return self._pad(mu, traj.y, 0.0), self._pad(var, traj.y, 1.0)
        return self._pad(mu, traj.y, 0.0, norm.y_mean), self._pad(var, traj.y, 1.0, norm.y_std**2)

    def forecast(self, traj: Trajectories, steps: int) -> Tensor:
        """(B, T+1, K, m) k-step forecasts, rolled out autoregressively on the model's own predictions.

        j = 0 is predict(traj). For j >= 1 the model reads z_0..z_{t-1} followed by
        [yhat_t, u_t], ..., [yhat_{t+j-1}, u_{t+j-1}] (the given future inputs, the predicted outputs) and
        yhat_{t+j} is its output at the last position, with the window semantics of predict: a
        context-limited model sees the last C of those inputs, a recurrent one all of them (in "stream" mode
        too; there j = 0 is the stream's one-step prediction). A Gaussian read-out feeds back its mean only
        (no sampling), so the forecast is the mean path, not the predictive mean of y_{t+j}. Entries with
        t + j > T are NaN. All origins advance together at the cost of the new inputs (mop.models.rollout);
        equal to reference_forecast to float rounding.
        """
        if self.cfg.forecast_mode == "gap":
            return self.gap_forecast(traj, steps)
        if self.cfg.forecast_mode == "direct":
            return self.direct_forecast(traj, steps)
        if not can_branch(self.model):
            if self._streams_exactly(traj.horizon):
                return self._streamed_forecast(traj, steps)
            return self.reference_forecast(traj, steps)
        z = self._inputs(traj)  # (B, T, d_in) normalised, model dtype
        first = None
        if self.mode == "stream" and self.model.context_limited and z.shape[1] > self.cfg.context:
            first = self.predict(traj).double()  # (B, T+1, m) the stream's one-step predictions
            if self.normalization is not None:
                norm = self.normalization
                first = (first - norm.y_mean.to(first.device)) / norm.y_std.to(first.device)
            first = first.to(z)
        chunk = self.chunk_size
        if self.model.context_limited:
            chunk = min(chunk, transformer_chunk_size(self.cfg, z.shape[1], steps))
        parts = []
        with torch.no_grad(), self._eval():
            for i in range(0, z.shape[0], chunk):
                part = None if first is None else first[i : i + chunk]
                parts.append(forecast_batch(self.model, z[i : i + chunk], steps, part))
        f = torch.cat(parts)  # (B, T+1, K, m) in the model's units
        if self.normalization is not None:
            f = self.normalization.outputs(f, None)[0]
        return f.to(device=traj.y.device, dtype=traj.y.dtype)

    def gap_forecast(self, traj: Trajectories, steps: int) -> Tensor:
        """(B, T+1, K, m) k-step forecasts of a model with an observation mask (model.forecast_mode =
        "gap"): the future outputs are read as missing, the future inputs as given.

        f[:, t, j] = predict(traj with y_t..y_{t+j-1} missing)[:, t + j], i.e. the model's prediction of
        y_{t+j} from y_0..y_{t-1} (and their gaps) and u_0..u_{t+j-1}, with the window semantics of predict.
        Nothing predicted is fed back, so errors do not compound through the inputs; a model trained with
        bursts of dropped outputs that are still scored (train.score_dropped) learns exactly this (a
        multi-step loss). Origins are batched in groups of GAP_ORIGINS, each cut to the rows it reads.
        """
        B, T1, m = traj.y.shape
        out = traj.y.new_full((B, T1, steps, m), float("nan"))
        for first in range(0, T1, GAP_ORIGINS):
            origins = range(first, min(first + GAP_ORIGINS, T1))
            rows = min(origins[-1] + steps, T1)  # the last origin reads up to row origins[-1] + K - 1
            y = traj.y[:, :rows].repeat(len(origins), 1, 1)  # (G*B, rows, m), origin-major
            for i, t in enumerate(origins):
                y[i * B : (i + 1) * B, t : t + steps - 1] = float("nan")
            u = None if traj.u is None else traj.u[:, :rows].repeat(len(origins), 1, 1)
            yhat = self.predict(Trajectories(y, u)).view(len(origins), B, rows, m)
            for i, t in enumerate(origins):
                j = min(steps, rows - t)
                out[:, t, :j] = yhat[i, :, t : t + j]
        return out

    def direct_forecast(self, traj: Trajectories, steps: int) -> Tensor:
        """(B, T+1, K, m) k-step forecasts read from the model's k-step heads (model.forecast_mode =
        "direct", model.horizons >= K): f[:, t, j] is head j+1 at the last input of z_0..z_{t-1}, the model's
        mean of y_{t+j} (j = 0 is predict(traj)). One forward per window, with the window semantics of
        predict (mode "window"; a context-limited model reads the last C inputs); nothing is fed back.
        f[:, 0, j] is the data-free prediction (0, or y_mean when normalised); entries with t + j > T are NaN.
        """
        if steps > self.cfg.horizons:
            raise MopError(
                f"this model has {self.cfg.horizons} forecast heads (model.horizons), so it forecasts at "
                f"most {self.cfg.horizons} steps, not {steps}; ask for fewer steps or train with "
                f"model.horizons={steps}"
            )
        z = self._inputs(traj)  # (B, T, d_in)
        with torch.no_grad(), self._eval():
            starts = range(0, z.shape[0], self.chunk_size)
            parts = [self._heads(z[i : i + self.chunk_size])[:, :, :steps] for i in starts]
        heads = torch.cat(parts)  # (B, T, K, m): position t - 1 forecasts y_t .. y_{t+K-1}
        if self.normalization is not None:
            heads = self.normalization.outputs(heads, None)[0]
        B, T1, m = traj.y.shape
        out = traj.y.new_full((B, T1, steps, m), float("nan"))
        first = 0.0 if self.normalization is None else self.normalization.y_mean.to(out)
        out[:, 0] = first  # no data: every head's prediction is the data-free one
        out[:, 1:] = heads.to(out)
        for j in range(1, steps):  # y_{t+j} beyond y_T does not exist
            out[:, T1 - j :, j] = float("nan")
        return out

    def _heads(self, z: Tensor) -> Tensor:
        """z (B, T, d_in) -> the k-step heads (B, T, K, m) with the window semantics of predict: position
        t >= C reads the window z_{t-C+1}..z_t, and every head its future inputs u_{t+1}.. from z."""
        B, T, _ = z.shape
        C, m, K = self.cfg.context, self.cfg.output_dim, self.cfg.horizons
        if not self.model.context_limited or T <= C:
            return self.model.forecast_heads(z)  # the future inputs are z's own, shifted
        future = own_future_inputs(z, self.cfg)  # (B, T, K-1, k)
        first = self.model.forecast_heads(z[:, :C], future=future[:, :C])  # (B, C, K, m)
        windows = later_windows(z, C)  # (B (T-C), C, d_in)
        later = future[:, C:].reshape(B * (T - C), 1, *future.shape[2:])  # (B (T-C), 1, K-1, k)
        step = self.chunk_size
        parts = [
            self.model.forecast_heads(windows[i : i + step], True, later[i : i + step])[:, -1]
            for i in range(0, windows.shape[0], step)
        ]  # each (b, K, m)
        return torch.cat([first, torch.cat(parts).view(B, T - C, K, m)], dim=1)

    @contextlib.contextmanager
    def _eval(self):
        was_training = self.model.training
        self.model.eval()
        try:
            yield
        finally:
            self.model.train(was_training)

    def reference_forecast(self, traj: Trajectories, steps: int) -> Tensor:
        """forecast by definition: one forward of the model per (origin t, step j), on the last C inputs of
        z_0..z_{t-1}, [yhat_t, u_t], .., [yhat_{t+j-1}, u_{t+j-1}] (the slow reference of the tests, and the
        path of a model without prefill/branch or a recurrent cache)."""
        yhat = self.predict(traj)  # (B, T+1, m)
        B, T1, m = yhat.shape
        out = yhat.new_full((B, T1, steps, m), float("nan"))
        out[:, :, 0] = yhat
        z = traj.model_inputs().double()  # (B, T+1, d_in) in data units
        u = None if traj.u is None else traj.u.double()
        context = self.cfg.context if self.model.context_limited else None
        for t in range(T1 - 1):
            hist, pred = z[:, :t], yhat[:, t].double()
            for j in range(1, min(steps, T1 - t)):
                new = fed_back(pred, u, t + j - 1)
                hist = torch.cat([hist, new[:, None]], dim=1)
                pred = self._last_output(hist if context is None else hist[:, -context:])
                out[:, t, j] = pred.to(out.dtype)
        return out

    def simulate(self, traj: Trajectories, context: int) -> Tensor:
        """(B, T+1-c, m) free-run simulation: forecast[:, c] alone (the model reads z_0..z_{c-1}, then its own
        predicted outputs with the given inputs). Where stepping the model's cache equals its forward (a
        recurrent model; a transformer with T <= context) the cache steps once per input, else one forward
        per simulated step (reference_simulate); model.forecast_mode = "gap": one predict with y_c..y_T read
        as missing."""
        if self.cfg.forecast_mode == "gap":
            y = traj.y.clone()
            y[:, context:] = float("nan")
            return self.predict(Trajectories(y, traj.u))[:, context:]
        if context > 0 and self._streams_exactly(traj.horizon):
            return self._streamed_simulation(traj, context)
        return self.reference_simulate(traj, context)

    def reference_simulate(self, traj: Trajectories, context: int) -> Tensor:
        """simulate by definition: one forward of the model per simulated step, on the last C inputs of
        z_0..z_{c-1} followed by the fed-back [yhat, u] (the slow reference of the tests)."""
        z = traj.model_inputs().double()  # (B, T+1, d_in)
        u = None if traj.u is None else traj.u.double()
        limit = self.cfg.context if self.model.context_limited else None
        hist = z[:, :context]
        pred = self._last_output(hist if limit is None else hist[:, -limit:])  # y_c from z_{<c}
        out = [pred]
        for t in range(context + 1, traj.horizon + 1):
            new = fed_back(pred, u, t - 1)
            hist = torch.cat([hist, new[:, None]], dim=1)
            pred = self._last_output(hist if limit is None else hist[:, -limit:])
            out.append(pred)
        return torch.stack(out, dim=1).to(traj.y.dtype)

    def _streams_exactly(self, horizon: int) -> bool:
        """Whether stepping the model's cache over T = horizon inputs equals its forward: a recurrent model
        always; a transformer while T <= its context (inside it, its cache and its features' running state
        equal the forward's, mop.models.transformer)."""
        if not self.model.supports_stream:
            return False
        return not self.model.context_limited or horizon <= self.cfg.context

    def _step(self, z: Tensor, cache) -> Tensor:
        """One input z (B, m + k) in data units through the model's cache -> its mean (B, m) in data units,
        float64 on the CPU."""
        mu = self.model.step(self._model_inputs(z[:, None])[:, 0], cache)
        if self.normalization is not None:
            mu = self.normalization.outputs(mu, None)[0]
        return mu.double().cpu()

    def _streamed_simulation(self, traj: Trajectories, context: int) -> Tensor:
        """simulate through the model's cache: c steps over z_0..z_{c-1}, then one per simulated output."""
        z = traj.model_inputs().double()  # (B, T+1, d_in) in data units
        u = None if traj.u is None else traj.u.double()
        with torch.no_grad(), self._eval():
            cache = self.model.init_cache(z.shape[0])
            for t in range(context):
                pred = self._step(z[:, t], cache)  # after z_{c-1}: the prediction of y_c
            out = [pred]
            for t in range(context + 1, traj.horizon + 1):
                new = fed_back(pred, u, t - 1)
                pred = self._step(new, cache)
                out.append(pred)
        return torch.stack(out, dim=1).to(traj.y.dtype)

    def _streamed_forecast(self, traj: Trajectories, steps: int) -> Tensor:
        """forecast through the model's cache (models without a branch path, e.g. with input features):
        one trunk steps over z_0..z_{T-1}; at each origin t a copy of it steps the K-1 fed-back inputs.
        Equal to reference_forecast where _streams_exactly; T + T (K-1) single steps instead of T (K-1)
        forwards of up to C inputs."""
        yhat = self.predict(traj)  # (B, T+1, m): j = 0
        B, T1, m = yhat.shape
        out = yhat.new_full((B, T1, steps, m), float("nan"))
        out[:, :, 0] = yhat
        z = traj.model_inputs().double()  # (B, T+1, d_in) in data units
        u = None if traj.u is None else traj.u.double()
        with torch.no_grad(), self._eval():
            trunk = self.model.init_cache(B)
            for t in range(T1 - 1):  # the trunk has read z_0..z_{t-1}
                if steps > 1:
                    branch, pred = copy.deepcopy(trunk), yhat[:, t].double().cpu()
                    for j in range(1, min(steps, T1 - t)):
                        new = fed_back(pred, u, t + j - 1)
                        pred = self._step(new, branch)
                        out[:, t, j] = pred.to(out)
                self._step(z[:, t], trunk)
        return out

    def _last_output(self, z: Tensor) -> Tensor:
        """The model's mean output (B, m) in data units, float64, at the last position of z (B, L, m + k)."""
        mu, _ = self._run(self._model_inputs(z), gaussian=False)
        return mu[:, -1].double().cpu()


def stream(model: nn.Module, z: Tensor, gaussian: bool = False) -> tuple[Tensor, Tensor | None]:
    """Step the model's cache over z (B, T, d_in) -> mean, var|None each (B, T, m)."""
    cache = model.init_cache(z.shape[0])
    outs = [model.step_distribution(z[:, t], cache) for t in range(z.shape[1])]  # T x ((B, m), (B, m)|None)
    mu = torch.stack([o[0] for o in outs], dim=1)
    var = torch.stack([o[1] for o in outs], dim=1) if gaussian else None
    return mu, var


def fed_back(pred: Tensor, u: Tensor | None, t: int) -> Tensor:
    """The model input a forecast feeds back: [pred, u_t] (B, m + k), or pred (B, m) without inputs."""
    return pred if u is None else torch.cat([pred, u[:, t]], dim=-1)


def later_windows(z: Tensor, context: int) -> Tensor:
    """The windows z_{t-C+1}..z_t for t = C..T-1, system-major: z (B, T, d_in) -> (B (T-C), C, d_in)."""
    windows = z.unfold(1, context, 1)[:, 1:]  # (B, T-C+1, d_in, C) -> drop the first: (B, T-C, d_in, C)
    return windows.permute(0, 1, 3, 2).reshape(-1, context, z.shape[-1])


def sliding_window(
    model: nn.Module, z: Tensor, gaussian: bool, context: int, windows_per_batch: int = 256
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
