"""Training and validation batches: inputs z_0..z_{T-1} (B, T, d_in), targets y_1..y_T (B, T, m).

num_source_systems = M > 0 draws M systems with one trajectory each once (on the training device) and samples
batches from them with a seeded generator; M = 0 draws fresh systems every batch. All training randomness
comes from one torch.Generator (saved in every checkpoint), so the same seed gives the same weights.

Recorded data (config.data, `mop train --data FILE`): RecordedData splits the file's trajectories with a
permutation seeded by data.split_seed, fits per-channel mean/std on the training split, and TrainingData
samples windows of train.horizon + 1 steps uniformly over all valid (trajectory, start) pairs of the
normalised training trajectories; num_source_systems is unused (the file fixes the systems).

Missing outputs: with train.missing_rate / missing_burst_rate > 0 (model.observation_mask) every batch has
outputs dropped at random (with_drop_outs, from the same generator); outputs missing in a recorded file (NaN)
stay missing. Targets then hold NaN where missing and the loss counts only the measured ones.
"""

from __future__ import annotations

import dataclasses
import functools
import os
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from mop.config import DataConfig, RunConfig, TrainConfig
from mop.errors import MopError
from mop.io import read_trajectories
from mop.missing import drop_mask, drop_outputs, masked_inputs
from mop.systems import make_family

NUM_VAL_SYSTEMS = 256


class TrainingData:
    """Batches of (inputs (B, T, d_in), targets (B, T, m)) on `device`, all randomness from one generator."""

    def __init__(self, config: RunConfig, device: torch.device) -> None:
        self.cfg = config.train
        self.masked = config.model.observation_mask
        self.generator = torch.Generator(device=device).manual_seed(self.cfg.seed)
        self.inputs = self.targets = None
        if config.data is not None:
            self.family = None
            self.windows = recorded_data(config.data).windows(config.data, self.cfg.horizon, device)
            return
        self.family = make_family(config.system)
        if self.cfg.num_source_systems > 0:
            self.inputs, self.targets = self._draw(self.cfg.num_source_systems)  # (M, T, d_in), (M, T, m)

    def _draw(self, num_systems: int) -> tuple[Tensor, Tensor]:
        traj = self.family.generate(num_systems, self.cfg.horizon, generator=self.generator)
        z = traj.model_inputs()  # (B, T+1, d_in)
        return z[:, :-1].float().contiguous(), traj.y[:, 1:].float().contiguous()

    def batch(self) -> tuple[Tensor, Tensor]:
        """(inputs (B, T, d_in), targets (B, T, m)); with a model that has an observation mask, targets hold
        NaN where an output is missing (dropped here, or missing in the data) and inputs the mask layout."""
        batch = self._clean_batch()
        return with_drop_outs(*batch, self.cfg, self.generator) if self.masked else batch

    def _clean_batch(self) -> tuple[Tensor, Tensor]:
        if self.family is None:
            return self.windows.sample(self.cfg.batch_size, self.generator)
        if self.inputs is None:
            return self._draw(self.cfg.batch_size)
        index = torch.randint(
            0,
            self.inputs.shape[0],
            (self.cfg.batch_size,),
            generator=self.generator,
            device=self.generator.device,
        )
        return self.inputs[index], self.targets[index]


def with_drop_outs(
    inputs: Tensor, targets: Tensor, cfg: TrainConfig, generator: torch.Generator
) -> tuple[Tensor, Tensor]:
    """Drop outputs (mop.missing.drop_mask with train.missing_rate / missing_burst_*; y_0 kept) from a batch
    inputs (B, T, m + k) = [y_0..y_{T-1}, u], targets (B, T, m) = y_1..y_T: a dropped y_t is missing both as
    the input at t and as the target at t - 1 (train.score_dropped: missing as the input only, the target
    keeps its value, so the loss scores predictions across gaps). Returns (masked inputs (B, T, m + k + m),
    targets with NaN where missing)."""
    m = targets.shape[-1]
    clean = torch.cat([inputs[:, :1, :m], targets], dim=1)  # (B, T+1, m): y_0..y_T (NaN where recorded so)
    drop = drop_mask(
        tuple(clean.shape), cfg.missing_rate, generator, cfg.missing_burst_rate, cfg.missing_burst_length
    )
    y = drop_outputs(clean, drop)
    z = torch.cat([y[:, :-1], inputs[..., m:]], dim=-1)
    scored = clean if cfg.score_dropped else y
    return masked_inputs(z, m), scored[:, 1:].contiguous()


def validation_batch(config: RunConfig, device: torch.device) -> tuple[Tensor, Tensor]:
    """Held-out systems (a generator seeded apart from training) for the validation loss.

    Recorded data: the first train.horizon + 1 steps of each held-out trajectory long enough for them.
    """
    g = torch.Generator(device=device).manual_seed(config.train.seed + 1_000_003)
    if config.data is not None:
        val = recorded_data(config.data).validation(config.data, config.train.horizon, device)
    else:
        family = make_family(config.system)
        traj = family.generate(NUM_VAL_SYSTEMS, config.train.horizon, generator=g)
        val = traj.model_inputs()[:, :-1].float(), traj.y[:, 1:].float()  # (N, T, d_in), (N, T, m)
    if config.model.observation_mask:  # the same kind of drop-outs as in training, seeded apart
        return with_drop_outs(*val, config.train, g)
    return val


# ----------------------------------------------------------------------------- recorded trajectories


@dataclasses.dataclass
class Windows:
    """Normalised training trajectories padded to (N, L, d_in) float32 and their valid windows (W, 2)."""

    z: Tensor  # (N, L, d_in): [y, u] per step, normalised, zero past each trajectory's end
    starts: Tensor  # (W, 2) long: (trajectory, first step) of every window of horizon + 1 steps
    horizon: int
    output_dim: int

    def sample(self, batch_size: int, generator: torch.Generator) -> tuple[Tensor, Tensor]:
        """Windows drawn uniformly (with replacement): inputs (B, T, d_in), targets (B, T, m)."""
        pick = torch.randint(
            0, self.starts.shape[0], (batch_size,), generator=generator, device=generator.device
        )
        traj, start = self.starts[pick, 0], self.starts[pick, 1]  # (B,), (B,)
        steps = start[:, None] + torch.arange(self.horizon + 1, device=start.device)  # (B, T+1)
        z = self.z[traj[:, None], steps]  # (B, T+1, d_in)
        return z[:, :-1].contiguous(), z[:, 1:, : self.output_dim].contiguous()


class RecordedData:
    """A file of recorded trajectories, split into training and validation by a seeded permutation.

    y: list of (T_i+1, m) float64 arrays in the file's units; u: list of (T_i+1, k) arrays (k = 0 without
    inputs). train_index / val_index: disjoint sorted trajectory indices.
    """

    def __init__(self, cfg: DataConfig) -> None:
        self.path = cfg.path
        _, data = read_trajectories(cfg.path)
        widths = {(y.shape[1], 0 if u is None else u.shape[1]) for y, u in data}
        if len(widths) != 1:
            raise MopError(f"{cfg.path}: trajectories differ in output/input widths {sorted(widths)}")
        (self.output_dim, self.input_dim), n = widths.pop(), len(data)
        self.y = [y for y, _ in data]
        self.num_missing = int(sum(np.isnan(y).sum() for y in self.y))  # outputs missing in the file
        self.u = [np.zeros((len(y), 0)) if u is None else u for y, u in data]
        n_val = int(round(cfg.validation_fraction * n))
        if n < 2 or not 1 <= n_val <= n - 1:
            raise MopError(
                f"{cfg.path}: {n} trajectories cannot be split into training and validation with "
                f"data.validation_fraction={cfg.validation_fraction}; need at least one of each"
            )
        order = np.random.default_rng(cfg.split_seed).permutation(n)
        self.val_index, self.train_index = np.sort(order[:n_val]), np.sort(order[n_val:])

    def fit(self) -> dict[str, list[float]]:
        """Per-channel mean and std (population, ddof 0; 1 for a constant channel) over every step of the
        training split, in the file's units: y_mean, y_std (m,), u_mean, u_std (k,)."""
        stats = {}
        for name, arrays in (("y", self.y), ("u", self.u)):
            a = np.concatenate([arrays[i] for i in self.train_index])  # (sum T_i+1, m or k)
            if np.isnan(a).all(axis=0).any():
                raise MopError(f"{self.path}: an output channel is missing at every training step")
            std = np.nanstd(a, axis=0)  # missing outputs (NaN) left out
            stats[f"{name}_mean"] = [float(v) for v in np.nanmean(a, axis=0)]
            stats[f"{name}_std"] = [float(v) if v > 0 else 1.0 for v in std]
        return stats

    def _normalised(self, cfg: DataConfig, index: np.ndarray) -> list[np.ndarray]:
        """[(T_i+1, m+k)] normalised [y, u] of the trajectories in `index`, float64."""
        mean = np.array([*cfg.y_mean, *cfg.u_mean])
        std = np.array([*cfg.y_std, *cfg.u_std])
        return [(np.concatenate([self.y[i], self.u[i]], axis=1) - mean) / std for i in index]

    def long_enough(self, index: np.ndarray, horizon: int) -> np.ndarray:
        return np.array([i for i in index if len(self.y[i]) >= horizon + 1], dtype=np.int64)

    def _check(self, index: np.ndarray, horizon: int, split: str) -> np.ndarray:
        kept = self.long_enough(index, horizon)
        if len(kept) == 0:
            longest = max(len(self.y[i]) for i in index) - 1
            raise MopError(
                f"{self.path}: no {split} trajectory has train.horizon + 1 = {horizon + 1} steps (the "
                f"longest has T = {longest}); lower train.horizon or record longer trajectories"
            )
        return kept

    def check_lengths(self, horizon: int) -> None:
        """MopError unless both splits hold a trajectory of at least horizon + 1 steps."""
        self._check(self.train_index, horizon, "training")
        self._check(self.val_index, horizon, "validation")

    def windows(self, cfg: DataConfig, horizon: int, device: torch.device) -> Windows:
        """Every window of horizon + 1 steps of the training trajectories at least that long."""
        kept = self._check(self.train_index, horizon, "training")
        z = self._normalised(cfg, kept)
        length = max(len(a) for a in z)
        padded = np.zeros((len(z), length, z[0].shape[1]), dtype=np.float32)
        starts = []
        for j, a in enumerate(z):
            padded[j, : len(a)] = a
            starts.extend((j, s) for s in range(len(a) - horizon))
        return Windows(
            z=torch.from_numpy(padded).to(device),
            starts=torch.tensor(starts, dtype=torch.long, device=device),
            horizon=horizon,
            output_dim=self.output_dim,
        )

    def validation(self, cfg: DataConfig, horizon: int, device: torch.device) -> tuple[Tensor, Tensor]:
        """The first horizon + 1 steps of each long-enough held-out trajectory: (N, T, d_in), (N, T, m)."""
        kept = self._check(self.val_index, horizon, "validation")
        z = np.stack([a[: horizon + 1] for a in self._normalised(cfg, kept)]).astype(np.float32)
        z = torch.from_numpy(z).to(device)  # (N, T+1, d_in)
        return z[:, :-1].contiguous(), z[:, 1:, : self.output_dim].contiguous()

    def summary(self, horizon: int) -> str:
        n_train, n_val = len(self.train_index), len(self.val_index)
        skipped = n_train - len(self.long_enough(self.train_index, horizon))
        skipped_val = n_val - len(self.long_enough(self.val_index, horizon))
        return (
            f"data {self.path}: {n_train + n_val} trajectories (m={self.output_dim}, k={self.input_dim}), "
            f"{n_train} training / {n_val} validation; {skipped} / {skipped_val} shorter than "
            f"train.horizon + 1 = {horizon + 1} steps skipped"
        )


def recorded_data(cfg: DataConfig) -> RecordedData:
    """RecordedData of cfg (read once per file version and split; callers must not modify it)."""
    path = Path(cfg.path)
    stat = path.stat() if path.is_file() else None
    key = (os.path.abspath(path), stat and (stat.st_mtime_ns, stat.st_size))
    return _recorded(key, cfg.path, cfg.validation_fraction, cfg.split_seed)


@functools.lru_cache(maxsize=2)
def _recorded(key: tuple, path: str, fraction: float, seed: int) -> RecordedData:
    return RecordedData(DataConfig(path=path, validation_fraction=fraction, split_seed=seed))
