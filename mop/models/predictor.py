"""The trained model as a Predictor: yhat[:, 0] = 0 and yhat[:, t] = model output at input position t-1.

The model reads z_t = [y_t, u_t] (traj.model_inputs()) for t = 0..T-1 and predicts y_1..y_T.
Trajectories longer than the training context C (T > C) are handled by `mode`:
- "window" (the paper's code): yhat_t uses the last C inputs z_{t-C}..z_{t-1}; one forward per window,
  windows batched.
- "stream": one step at a time with the model's key-value cache (see mop.models.transformer), constant cost
  per step. Equal to "window" for t <= C; beyond C it is the rolling-cache approximation documented there.
For T <= C both modes equal a single forward pass. A model without a context limit (context_limited = False,
the GRU) runs the full recurrence in both modes (streaming it is exact).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from mop.errors import MopError
from mop.systems.base import Trajectories


class LearnedPredictor:
    """Predictor protocol around a model of mop.models.build_model (run in eval mode, no grad, in chunks)."""

    def __init__(
        self, model: nn.Module, name: str = "mop", mode: str = "window", chunk_size: int = 256
    ) -> None:
        if mode not in ("window", "stream"):
            raise MopError(f"predictor mode must be 'window' or 'stream', got {mode!r}")
        if chunk_size <= 0:
            raise MopError(f"chunk_size must be positive, got {chunk_size}")
        self.model, self.name, self.mode, self.chunk_size = model, name, mode, chunk_size
        self.cfg = model.cfg

    def _inputs(self, traj: Trajectories) -> Tensor:
        z = traj.model_inputs()  # (B, T+1, d_in)
        if z.shape[-1] != self.cfg.input_dim or traj.output_dim != self.cfg.output_dim:
            raise MopError(
                f"trajectories have output_dim={traj.output_dim}, input width {z.shape[-1]}, "
                f"but the model expects output_dim={self.cfg.output_dim}, "
                f"input width {self.cfg.input_dim}; use a model trained on this family"
            )
        p = next(self.model.parameters())
        return z[:, :-1].to(device=p.device, dtype=p.dtype)  # (B, T, d_in): z_0..z_{T-1}

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

    def _pad(self, out: Tensor, like: Tensor, fill: float) -> Tensor:
        """Prepend the data-free prediction for y_0: (B, T, m) -> (B, T+1, m)."""
        first = torch.full_like(out[:, :1], fill)
        return torch.cat([first, out], dim=1).to(device=like.device, dtype=like.dtype)

    def predict(self, traj: Trajectories) -> Tensor:
        """(B, T+1, m): yhat[:, 0] = 0, yhat[:, t] from z_0..z_{t-1}."""
        mu, _ = self._run(self._inputs(traj), gaussian=False)
        return self._pad(mu, traj.y, 0.0)

    def predict_distribution(self, traj: Trajectories) -> tuple[Tensor, Tensor]:
        """Gaussian readout: (mean, var) each (B, T+1, m); index 0 is (0, 1) by convention (no data)."""
        if self.cfg.readout != "gaussian":
            raise MopError("predict_distribution needs a model with readout='gaussian'")
        mu, var = self._run(self._inputs(traj), gaussian=True)
        return self._pad(mu, traj.y, 0.0), self._pad(var, traj.y, 1.0)


def stream(model: nn.Module, z: Tensor, gaussian: bool = False) -> tuple[Tensor, Tensor | None]:
    """Step the model's cache over z (B, T, d_in) -> mean, var|None each (B, T, m)."""
    cache = model.init_cache(z.shape[0])
    outs = [model.step_distribution(z[:, t], cache) for t in range(z.shape[1])]  # T x ((B, m), (B, m)|None)
    mu = torch.stack([o[0] for o in outs], dim=1)
    var = torch.stack([o[1] for o in outs], dim=1) if gaussian else None
    return mu, var


def sliding_window(
    model: nn.Module, z: Tensor, gaussian: bool, context: int, windows_per_batch: int = 256
) -> tuple[Tensor, Tensor | None]:
    """The paper's sliding window: output t (t >= C) is the last output of a forward on z_{t-C+1}..z_t.

    Outputs 0..C-1 come from one forward on z_0..z_{C-1}. z (B, T, d_in) -> mean, var|None each (B, T, m).
    """
    B, T, d_in = z.shape
    run = (lambda x: model.predict_distribution(x)) if gaussian else (lambda x: (model(x), None))
    mu0, var0 = run(z[:, :context])  # (B, C, m)
    windows = z.unfold(1, context, 1)[:, 1:]  # (B, T-C+1, d_in, C) -> drop first: (B, T-C, d_in, C)
    windows = windows.permute(0, 1, 3, 2).reshape(-1, context, d_in)  # (B*(T-C), C, d_in)
    mus, vars_ = [], []
    for i in range(0, windows.shape[0], windows_per_batch):
        mu, var = run(windows[i : i + windows_per_batch])  # (b, C, m)
        mus.append(mu[:, -1])
        vars_.append(None if var is None else var[:, -1])
    mu = torch.cat([mu0, torch.cat(mus).view(B, T - context, -1)], dim=1)  # (B, T, m)
    var = torch.cat([var0, torch.cat(vars_).view(B, T - context, -1)], dim=1) if gaussian else None
    return mu, var
