"""A deep-LRU simulator fitted on its simulation error (mop.simulators).

Time convention (as mop.predictors.simulate): given y_0..y_{c-1} and every input, the simulator predicts
y_c..y_T. An encoder reads the last n = init_window measured steps before c, (y, u)_{c-n..c-1}, and gives
the initial states of the deep LRU's layers; the deep LRU then maps u_c..u_T to y_c..y_T, with no output
fed back. Training draws subsections of the estimation record's training part, n measured steps and then
`subsection` simulated ones, and minimises the mean squared simulation error over the simulated steps
(normalised units), its gradient through the whole rollout (a parallel scan: no truncation needed). The
same `simulate_segment` trains and predicts. The weights kept are those that simulate the held-out end of
each estimation record best (checked every `check_every` steps), the early stopping SUBNET also uses.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Sequence

import numpy as np
import torch
from torch import Tensor, nn

from mop.errors import MopError
from mop.record import Record
from mop.simulators.lru import DeepLRU
from mop.systems.base import Trajectories


@dataclasses.dataclass(frozen=True)
class SimulatorConfig:
    """init_window: n measured steps the encoder reads; subsection: simulated steps per training sample;
    width, state, layers: the deep LRU's; batch, steps, lr: Adam's (the rate decays by cosine to a tenth);
    holdout: the share of each record's end that chooses the weights; seed: weights and sampling."""

    init_window: int = 50
    subsection: int = 200
    width: int = 32
    state: int = 32
    layers: int = 2
    encoder_width: int = 64
    batch: int = 32
    steps: int = 2000
    lr: float = 2e-3
    holdout: float = 0.2
    check_every: int = 100
    seed: int = 0


class Simulator(nn.Module):
    """The encoder and the deep LRU (see the module docstring), in normalised units."""

    def __init__(self, outputs: int, inputs: int, cfg: SimulatorConfig) -> None:
        super().__init__()
        n, L, N = cfg.init_window, cfg.layers, cfg.state
        self.encoder = nn.Sequential(
            nn.Linear(n * (outputs + inputs), cfg.encoder_width),
            nn.Tanh(),
            nn.Linear(cfg.encoder_width, 2 * L * N),
        )
        self.body = DeepLRU(inputs, outputs, cfg.width, N, L)
        self.layers, self.state = L, N

    def simulate_segment(self, window: Tensor, future_u: Tensor, loop: bool = False) -> Tensor:
        """window (B, n, m + k): the measured (y, u) before the simulation; future_u (B, T, k) -> the
        simulated outputs (B, T, m)."""
        h = self.encoder(window.flatten(1)).view(window.shape[0], self.layers, 2, self.state)
        h0 = [torch.complex(h[:, i, 0], h[:, i, 1]) for i in range(self.layers)]
        return self.body(future_u, h0, loop=loop)


@dataclasses.dataclass
class Scaling:
    """Per-channel mean and std of the estimation record's outputs and inputs."""

    y_mean: np.ndarray
    y_std: np.ndarray
    u_mean: np.ndarray
    u_std: np.ndarray

    @classmethod
    def of(cls, records: Sequence[Record]) -> Scaling:
        y = np.concatenate([r.y for r in records])
        u = np.concatenate([r.u for r in records])
        return cls(y.mean(0), np.maximum(y.std(0), 1e-12), u.mean(0), np.maximum(u.std(0), 1e-12))

    def z(self, y: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return (y - self.y_mean) / self.y_std, (u - self.u_mean) / self.u_std


def _check(records: Sequence[Record], cfg: SimulatorConfig) -> None:
    if not records or any(r.u is None for r in records):
        raise MopError("a simulator maps inputs to outputs: give records with an input column u0")
    if any(np.isnan(r.y).any() for r in records):
        raise MopError("the simulator's estimation records must have every output; fill the gaps")
    shortest = min(len(r) for r in records)
    need = cfg.init_window + 2
    if int(shortest * (1 - cfg.holdout)) < need or int(shortest * cfg.holdout) < need:
        raise MopError(
            f"a record of {shortest} steps is too short for the simulator's init_window {cfg.init_window}: "
            "give longer records or a smaller window"
        )


def fit_simulator(records: Sequence[Record], cfg: SimulatorConfig = SimulatorConfig()) -> SimulatorPredictor:
    """The simulator fitted on `records` (see the module docstring); its predictor."""
    records = list(records)
    _check(records, cfg)
    cut = [int(len(r) * (1 - cfg.holdout)) for r in records]
    scaling = Scaling.of([r[:c] for r, c in zip(records, cut, strict=True)])
    train = [scaling.z(r.y[:c], r.u[:c]) for r, c in zip(records, cut, strict=True)]
    held = [scaling.z(r.y[c:], r.u[c:]) for r, c in zip(records, cut, strict=True)]
    n = cfg.init_window
    length = min(cfg.subsection, min(len(y) for y, _ in train) - n)
    starts = [(i, s) for i, (y, _) in enumerate(train) for s in range(len(y) - n - length + 1)]
    m, k = records[0].num_outputs, records[0].num_inputs
    with torch.random.fork_rng():
        torch.manual_seed(cfg.seed)
        model = Simulator(m, k, cfg).double()
    generator = torch.Generator().manual_seed(cfg.seed)
    data = [(torch.from_numpy(y), torch.from_numpy(u)) for y, u in train]
    optimizer = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    schedule = torch.optim.lr_scheduler.LambdaLR(
        optimizer, lambda s: 0.1 + 0.45 * (1 + math.cos(math.pi * min(s, cfg.steps) / cfg.steps))
    )
    initial = _held_out(model, held, n)
    best, best_score, history = copy.deepcopy(model.state_dict()), initial, []
    for step in range(1, cfg.steps + 1):
        picks = torch.randint(len(starts), (cfg.batch,), generator=generator).tolist()
        window, future_u, target = _batch([starts[p] for p in picks], data, n, length)
        loss = ((model.simulate_segment(window, future_u) - target) ** 2).mean()
        optimizer.zero_grad()
        loss.backward()
        nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        optimizer.step()
        schedule.step()
        if step % cfg.check_every == 0 or step == cfg.steps:
            score = _held_out(model, held, n)
            history.append((step, loss.item(), score))
            if score < best_score:
                best, best_score = copy.deepcopy(model.state_dict()), score
    model.load_state_dict(best)
    return SimulatorPredictor(
        model, scaling, cfg, held_out_rmse=best_score, initial_held_out_rmse=initial, history=history
    )


def _batch(picks, data, n: int, length: int) -> tuple[Tensor, Tensor, Tensor]:
    windows, futures, targets = [], [], []
    for i, s in picks:
        y, u = data[i]
        windows.append(torch.cat([y[s : s + n], u[s : s + n]], dim=-1))
        futures.append(u[s + n : s + n + length])
        targets.append(y[s + n : s + n + length])
    return torch.stack(windows), torch.stack(futures), torch.stack(targets)


@torch.no_grad()
def _held_out(model: Simulator, held, n: int) -> float:
    """The RMSE (normalised units) of each held-out part simulated after its first n steps, pooled."""
    errors = []
    for y, u in held:
        y, u = torch.from_numpy(y), torch.from_numpy(u)
        window = torch.cat([y[:n], u[:n]], dim=-1)[None]
        sim = model.simulate_segment(window, u[n:][None])[0]
        errors.append(((sim - y[n:]) ** 2).flatten())
    value = float(torch.cat(errors).mean().sqrt())
    return value if math.isfinite(value) else math.inf


class SimulatorPredictor:
    """The fitted simulator as a mop Predictor: simulate(traj, context) and predict(traj) in the data's
    units (traj's y (B, T+1, m), u (B, T+1, k))."""

    def __init__(self, model: Simulator, scaling: Scaling, cfg: SimulatorConfig, **info) -> None:
        self.model, self.scaling, self.cfg, self.info = model.eval(), scaling, cfg, info
        self.name = "lru"

    def _z(self, traj: Trajectories) -> tuple[Tensor, Tensor]:
        if traj.u is None or traj.u.shape[-1] != len(self.scaling.u_mean):
            raise MopError(f"the simulator reads {len(self.scaling.u_mean)} input(s); give records with them")
        y, u = self.scaling.z(traj.y.double().numpy(), traj.u.double().numpy())
        return torch.from_numpy(y), torch.from_numpy(u)

    def _window(self, y: Tensor, u: Tensor, end: int) -> Tensor:
        """(B, n, m + k): the n steps before `end`, the first step repeated where fewer were measured."""
        n = self.cfg.init_window
        idx = torch.clamp(torch.arange(end - n, end), min=0)
        return torch.cat([torch.nan_to_num(y[:, idx]), u[:, idx]], dim=-1)

    @torch.no_grad()
    def simulate(self, traj: Trajectories, context: int) -> Tensor:
        """(B, T+1-c, m): y_c..y_T from the n measured steps before c and the inputs."""
        y, u = self._z(traj)
        sim = self.model.simulate_segment(self._window(y, u, context), u[:, context:])
        return torch.from_numpy(sim.numpy() * self.scaling.y_std + self.scaling.y_mean).to(traj.y.dtype)

    @torch.no_grad()
    def predict(self, traj: Trajectories) -> Tensor:
        """(B, T+1, m): y_t simulated one step from the n steps before t (y_0: the first output repeated)."""
        y, u = self._z(traj)
        out = torch.empty_like(y)
        for t in range(y.shape[1]):
            out[:, t] = self.model.simulate_segment(self._window(y, u, max(t, 1)), u[:, t : t + 1])[:, 0]
        return torch.from_numpy(out.numpy() * self.scaling.y_std + self.scaling.y_mean).to(traj.y.dtype)


def simulator_line(predictor: SimulatorPredictor) -> str:
    """One line on what was fitted: the deep LRU's size, the training and the held-out choice."""
    cfg, info = predictor.cfg, predictor.info
    best = min(info["history"], key=lambda h: h[2], default=(0, 0.0, info["held_out_rmse"]))
    return (
        f"a deep LRU ({cfg.layers} x {cfg.width}, state {cfg.state}) fitted on its simulation error over "
        f"subsections of {cfg.subsection} steps after {cfg.init_window} measured, {cfg.steps} steps of batch "
        f"{cfg.batch}, seed {cfg.seed}; held-out simulation RMSE (normalised) {info['held_out_rmse']:.4g} "
        f"(step {best[0] if best[2] == info['held_out_rmse'] else 0}; at the start "
        f"{info['initial_held_out_rmse']:.4g})"
    )
