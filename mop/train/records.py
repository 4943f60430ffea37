"""Recorded trajectories to train on (`mop train --data FILE [--val FILE]`): the split, the normalisation and
the windows.

Three ways to hold out validation data (data.split, reported by `summary`):
- "trajectory": a seeded permutation (data.split_seed) holds out round(data.validation_fraction * n) whole
  trajectories; the validation batch is the first train.horizon + 1 steps of each held-out trajectory. For
  many short trajectories (one per system, as `mop simulate` writes them).
- "time": every trajectory is cut in time; its first steps train, its last ceil(validation_fraction * L_i)
  steps validate, and no window crosses the cut. For one long record or a few, as identification data comes.
- "file": `--val FILE` (data.validation_path) is the validation record and every step of data.path trains.
"auto" (the default) is "trajectory" wherever that split holds at least one trajectory on each side (as
before the other splits existed), else "time".

Every part is an array (L, m + k) of [y_t, u_t] in the file's units. The validation batch of the "time" and
"file" splits is every window of train.horizon + 1 steps of the validation parts, thinned evenly to at most
MAX_VALIDATION_WINDOWS (for a model validated by simulation, mop.train.data.validates_tails, the "time"
split's tails after the steps before them instead: tail_windows). Per-channel mean / std are fitted on the
training parts only.

The records themselves are read once, at the edge (`mop train`'s command, or the caller's own
mop.read_records), and handed down as TrainingRecords: the recipe and the trainer split them
(TrainingRecords.split) and never read a file again. recorded_data(cfg) reads cfg's files for a caller that
has only a config (a run reloaded later, a config file naming its data).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from mop.config import DataConfig
from mop.errors import MopError
from mop.filters.arx import least_squares_coefficients
from mop.record import Record, read_records

MAX_VALIDATION_WINDOWS = 256
RIDGE = 1e-6  # relative ridge of fit_prior's least squares


@dataclasses.dataclass
class Windows:
    """Normalised training parts padded to (N, L, d_in) float32 and their valid windows (W, 2)."""

    z: Tensor  # (N, L, d_in): [y, u] per step, normalised, zero past each part's end
    starts: Tensor  # (W, 2) long: (part, first step) of every window of horizon + 1 steps
    horizon: int
    output_dim: int

    def sample(self, batch_size: int, generator: torch.Generator) -> tuple[Tensor, Tensor]:
        """Windows drawn uniformly (with replacement): inputs (B, T, d_in), targets (B, T, m)."""
        pick = torch.randint(
            0, self.starts.shape[0], (batch_size,), generator=generator, device=generator.device
        )
        part, start = self.starts[pick, 0], self.starts[pick, 1]  # (B,), (B,)
        steps = start[:, None] + torch.arange(self.horizon + 1, device=start.device)  # (B, T+1)
        z = self.z[part[:, None], steps]  # (B, T+1, d_in)
        return z[:, :-1].contiguous(), z[:, 1:, : self.output_dim].contiguous()


def _widths(path: str, records: list[Record]) -> tuple[int, int]:
    """(m, k) shared by every record, or a one-line MopError."""
    widths = {(r.num_outputs, r.num_inputs) for r in records}
    if len(widths) != 1:
        raise MopError(f"{path}: trajectories differ in output/input widths {sorted(widths)}")
    return widths.pop()


def _joined(records: list[Record]) -> list[np.ndarray]:
    """[(L_i, m + k)] [y, u] of each record (k = 0 without inputs), float64."""
    return [r.y if r.u is None else np.concatenate([r.y, r.u], axis=1) for r in records]


def choose_split(split: str, num_trajectories: int, fraction: float) -> str:
    """The split "auto" resolves to for a file of `num_trajectories` (no separate validation file)."""
    if split != "auto":
        return split
    held_out = int(round(fraction * num_trajectories))
    return "trajectory" if 1 <= held_out <= num_trajectories - 1 else "time"


def window_count(parts: list[np.ndarray], horizon: int) -> int:
    """Windows of horizon + 1 consecutive steps inside the parts."""
    return sum(max(0, len(a) - horizon) for a in parts)


@dataclasses.dataclass(frozen=True, eq=False)
class TrainingPart:
    """The training part of a split record as a recipe plans from it, made once (RecordedData.training_part)
    and handed down whole, so the planner never calls back for more: `pairs` [(y (L, m), u (L, k))] in the
    record's units, `normalised` the same pairs as the network reads them (normalised on the training part's
    moments; None where outputs are missing), `lengths` the parts' lengths (the windows a budget buys) and
    `source` where the record came from (for messages)."""

    source: str
    pairs: list[tuple[np.ndarray, np.ndarray]]
    normalised: list[tuple[np.ndarray, np.ndarray]] | None
    lengths: tuple[int, ...]


@dataclasses.dataclass(frozen=True, eq=False)
class TrainingRecords:
    """The records a run on recorded data trains on, in memory: the estimation records, the validation
    records (`--val`; None: held out of the estimation records by data.split) and where they came from
    (`source`, `validation_source`: the files' paths, or the records' names; data.path and
    data.validation_path keep them as provenance only)."""

    records: tuple[Record, ...]
    validation: tuple[Record, ...] | None = None
    source: str = "records"
    validation_source: str = ""
    _splits: dict = dataclasses.field(default_factory=dict, repr=False)

    @classmethod
    def read(
        cls, path: str | os.PathLike, validation_path: str | os.PathLike | None = None
    ) -> TrainingRecords:
        """The records of the file at `path` (and of the validation file), each read once: the edge."""
        validation = None if not validation_path else tuple(read_records(validation_path))
        return cls(tuple(read_records(path)), validation, str(path), str(validation_path or ""))

    def split(self, cfg: DataConfig) -> RecordedData:
        """The records split as cfg asks (data.validation_fraction, data.split_seed, data.split), made once
        per split; callers must not modify it."""
        key = (cfg.validation_fraction, cfg.split_seed, cfg.split)
        if key not in self._splits:
            self._splits[key] = RecordedData(cfg, self)
        return self._splits[key]


class RecordedData:
    """Recorded trajectories split into training and validation parts (see the module docstring).

    train_parts / val_parts: lists of (L, m + k) float64 arrays in the records' units; train_index /
    val_index: the trajectories on each side of a "trajectory" split (None for the others). `given`: the
    records in memory (TrainingRecords), kept as `given` (the whole records, before the split); it reads no
    file (read_recorded reads cfg's).
    """

    def __init__(self, cfg: DataConfig, given: TrainingRecords) -> None:
        self.given, self.path = given, given.source
        records = list(given.records)
        self.output_dim, self.input_dim = _widths(self.path, records)
        self.num_trajectories = len(records)
        self.num_missing = int(sum(np.isnan(r.y).sum() for r in records))  # outputs missing in the file
        self.train_index = self.val_index = None
        parts = _joined(records)
        if given.validation is not None:
            self.split = "file"
            self.train_parts = parts
            self.val_parts = self._validation_file(given.validation_source, list(given.validation))
        else:
            self.split = choose_split(cfg.split, len(parts), cfg.validation_fraction)
            cut = self._by_trajectory if self.split == "trajectory" else self._in_time
            self.train_parts, self.val_parts = cut(parts, cfg)

    def _validation_file(self, path: str, records: list[Record]) -> list[np.ndarray]:
        widths = _widths(path, records)
        if widths != (self.output_dim, self.input_dim):
            raise MopError(
                f"--val {path} has m={widths[0]} outputs and k={widths[1]} inputs, but {self.path} has "
                f"m={self.output_dim}, k={self.input_dim}; give a validation record of the same plant"
            )
        self.num_missing += int(sum(np.isnan(r.y).sum() for r in records))
        return _joined(records)

    def _by_trajectory(self, parts: list[np.ndarray], cfg: DataConfig) -> tuple[list, list]:
        n, n_val = len(parts), int(round(cfg.validation_fraction * len(parts)))
        if n < 2 or not 1 <= n_val <= n - 1:
            raise MopError(
                f"{self.path}: {n} trajectories cannot be split into training and validation with "
                f"data.validation_fraction={cfg.validation_fraction}; use data.split=time (or auto), or --val"
            )
        order = np.random.default_rng(cfg.split_seed).permutation(n)
        self.val_index, self.train_index = np.sort(order[:n_val]), np.sort(order[n_val:])
        return [parts[i] for i in self.train_index], [parts[i] for i in self.val_index]

    @staticmethod
    def _in_time(parts: list[np.ndarray], cfg: DataConfig) -> tuple[list, list]:
        cuts = [len(a) - math.ceil(cfg.validation_fraction * len(a)) for a in parts]
        pairs = list(zip(parts, cuts, strict=True))
        return [a[:c] for a, c in pairs], [a[c:] for a, c in pairs]

    def fit(self) -> dict[str, list[float]]:
        """Per-channel mean and std (population, ddof 0; 1 for a constant channel) over every step of the
        training parts, in the file's units: y_mean, y_std (m,), u_mean, u_std (k,)."""
        a = np.concatenate(self.train_parts)  # (sum L_i, m + k)
        m = self.output_dim
        if np.isnan(a[:, :m]).all(axis=0).any():
            raise MopError(f"{self.path}: an output channel is missing at every training step")
        mean, std = np.nanmean(a, axis=0), np.nanstd(a, axis=0)  # missing outputs (NaN) left out
        std = np.where(std > 0, std, 1.0)
        as_list = lambda v: [float(x) for x in v]  # noqa: E731
        return {
            "y_mean": as_list(mean[:m]),
            "y_std": as_list(std[:m]),
            "u_mean": as_list(mean[m:]),
            "u_std": as_list(std[m:]),
        }

    def normalised(self, cfg: DataConfig, parts: list[np.ndarray]) -> list[np.ndarray]:
        """[(L_i, m + k)] normalised parts, float64."""
        mean = np.array([*cfg.y_mean, *cfg.u_mean])
        std = np.array([*cfg.y_std, *cfg.u_std])
        return [(a - mean) / std for a in parts]

    def _long_enough(self, parts: list[np.ndarray], horizon: int, side: str) -> list[np.ndarray]:
        kept = [a for a in parts if len(a) >= horizon + 1]
        if kept:
            return kept
        longest = max(len(a) for a in parts)
        if self.split == "time":
            total = max(len(a) + len(b) for a, b in zip(self.train_parts, self.val_parts, strict=True))
            raise MopError(
                f"{self.path}: split in time, the longest {side} part has {longest} of {total} steps, fewer "
                f"than train.horizon + 1 = {horizon + 1}; lower train.horizon, change "
                "data.validation_fraction, or give a validation record with --val FILE"
            )
        what = "trajectory" if self.split == "trajectory" else "--val trajectory"
        raise MopError(
            f"{self.path}: no {side} {what} has train.horizon + 1 = {horizon + 1} steps (the longest has "
            f"T = {longest - 1}); lower train.horizon or record longer trajectories"
        )

    def check_lengths(self, horizon: int, tails: bool = False) -> None:
        """MopError unless both sides hold a part of at least horizon + 1 steps (tails, split in time: the
        validation side is the held-out tails after the steps before them, tail_windows: a whole trajectory
        that long)."""
        self._long_enough(self.train_parts, horizon, "training")
        if not (tails and self.split == "time"):
            self._long_enough(self.val_parts, horizon, "validation")

    def windows(self, cfg: DataConfig, horizon: int, device: torch.device) -> Windows:
        """Every window of horizon + 1 steps of the training parts at least that long."""
        z = self.normalised(cfg, self._long_enough(self.train_parts, horizon, "training"))
        padded = np.zeros((len(z), max(len(a) for a in z), z[0].shape[1]), dtype=np.float32)
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

    def validation_windows(self, horizon: int) -> list[tuple[int, int]]:
        """(part, first step) of the validation windows: the first window of each held-out trajectory
        ("trajectory"), else every window of the parts thinned evenly to MAX_VALIDATION_WINDOWS."""
        parts = self.val_parts
        if self.split == "trajectory":
            return [(j, 0) for j, a in enumerate(parts) if len(a) >= horizon + 1]
        every = [(j, s) for j, a in enumerate(parts) for s in range(len(a) - horizon)]
        if len(every) <= MAX_VALIDATION_WINDOWS:
            return every
        keep = np.linspace(0, len(every) - 1, MAX_VALIDATION_WINDOWS).round().astype(int)
        return [every[i] for i in keep]

    def validation(self, cfg: DataConfig, horizon: int, device: torch.device) -> tuple[Tensor, Tensor]:
        """The validation windows (validation_windows): inputs (N, T, d_in), targets (N, T, m)."""
        z = self.validation_steps(cfg, horizon).to(device)  # (N, T+1, d_in)
        return z[:, :-1].contiguous(), z[:, 1:, : self.output_dim].contiguous()

    def validation_steps(self, cfg: DataConfig, horizon: int) -> Tensor:
        """The validation windows' steps z_0..z_T (N, T+1, m + k), normalised, float32."""
        self._long_enough(self.val_parts, horizon, "validation")
        parts = self.normalised(cfg, self.val_parts)
        windows = [parts[j][s : s + horizon + 1] for j, s in self.validation_windows(horizon)]
        return torch.from_numpy(np.stack(windows).astype(np.float32))

    def tail_windows(self, cfg: DataConfig, horizon: int, after: int) -> tuple[Tensor, Tensor]:
        """The "time" split's held-out tails, each after the recorded steps before it (validation by free-run
        simulation): for every trajectory of at least horizon + 1 steps, the horizon + 1 normalised steps
        that start max(after, horizon + 1 - tail) steps before its held-out tail of `tail` steps (as many as
        the training part has, at most), and the cut: the index in the window of the first held-out step.
        Returns (windows (N, horizon + 1, m + k) float32, cuts (N,) long)."""
        windows, cuts = [], []
        parts = self.normalised(cfg, self.train_parts), self.normalised(cfg, self.val_parts)
        for a, b in zip(*parts, strict=True):
            if len(a) + len(b) < horizon + 1:
                continue
            before = min(len(a), max(after, horizon + 1 - len(b)))
            windows.append(np.concatenate([a[len(a) - before :], b])[: horizon + 1])
            cuts.append(before)
        if not windows:
            longest = max(len(a) + len(b) for a, b in zip(self.train_parts, self.val_parts, strict=True))
            raise MopError(
                f"{self.path}: no trajectory has train.horizon + 1 = {horizon + 1} steps (the longest has "
                f"{longest}); lower train.horizon or give a validation record with --val FILE"
            )
        z = torch.from_numpy(np.stack(windows).astype(np.float32))
        return z, torch.tensor(cuts, dtype=torch.long)

    def fit_prior(self, cfg: DataConfig, p: int, q: int, offset: bool, cubes: int = 0) -> list[float]:
        """The ARX(p, q) coefficients (d, m) flattened, by least squares on the normalised training parts:
        the pairs (phi_{s-1}, y_s), s >= max(p, q), with phi as mop.filters.arx.arx_regressors (the rows the
        RLS / ARX feature of the model regresses on; a ridge of RIDGE for collinear inputs)."""
        try:
            theta = least_squares_coefficients(
                self.normalised(cfg, self.train_parts), self.output_dim, p, q, offset, cubes, RIDGE
            )
        except MopError:
            gaps = f"{self.path}: model.rls_prior=fit needs complete outputs; fill the gaps"
            raise MopError(gaps) from None
        return [float(v) for v in theta.reshape(-1)]

    @functools.cached_property
    def training_part(self) -> TrainingPart:
        """The training part handed to a recipe's planner (TrainingPart), made once per split."""
        m = self.output_dim
        normalised = None
        if not self.num_missing:
            z = self.normalised(DataConfig(path=self.path, **self.fit()), self.train_parts)
            normalised = [(a[:, :m], a[:, m:]) for a in z]
        pairs = [(a[:, :m], a[:, m:]) for a in self.train_parts]
        return TrainingPart(self.path, pairs, normalised, tuple(len(a) for a in self.train_parts))

    def records(self, parts: list[np.ndarray]) -> list[Record]:
        """`parts` (train_parts, val_parts, or normalised ones) as records: y their first m columns, u the
        rest (None without inputs)."""
        m = self.output_dim
        return [Record(y=a[:, :m], u=a[:, m:] if self.input_dim else None) for a in parts]

    def summary(self, horizon: int, tails: bool = False) -> str:
        """One line: the file, its shape, the split and the windows of horizon + 1 steps on each side (tails,
        split in time: the validation side is the held-out tails, tail_windows)."""
        n_train, n_val = len(self.train_parts), len(self.val_parts)
        skipped = sum(len(a) < horizon + 1 for a in self.train_parts)
        skipped_val = sum(len(a) < horizon + 1 for a in self.val_parts)
        tails = tails and self.split == "time"
        if tails:
            whole = [len(a) + len(b) for a, b in zip(self.train_parts, self.val_parts, strict=True)]
            skipped_val = sum(n < horizon + 1 for n in whole)
            n_tails = len(whole) - skipped_val
        split = {
            "trajectory": f"split by trajectory: {n_train} training / {n_val} validation",
            "time": f"split in time: the last {self._val_share()} steps validate",
            "file": f"validation from --val ({_count(n_val, 'trajectory', 'trajectories')})",
        }[self.split]
        return (
            f"data {self.path}: {_count(self.num_trajectories, 'trajectory', 'trajectories')} "
            f"(m={self.output_dim}, k={self.input_dim}), "
            f"{split}; {window_count(self.train_parts, horizon)} training / "
            + (
                f"{n_tails} validation windows (the held-out tail simulated after the steps before it)"
                if tails
                else f"{len(self.validation_windows(horizon))} validation windows"
            )
            + f" of {horizon + 1} steps; "
            f"{skipped} / {skipped_val} shorter than train.horizon + 1 = {horizon + 1} steps skipped"
        )

    def _val_share(self) -> str:
        steps = sum(len(a) for a in self.val_parts)
        total = steps + sum(len(a) for a in self.train_parts)
        each = " (the end of each trajectory)" if len(self.val_parts) > 1 else ""
        return f"{steps} of {total}{each}"


def _count(n: int, one: str, many: str) -> str:
    return f"{n} {one if n == 1 else many}"


def read_recorded(cfg: DataConfig) -> RecordedData:
    """RecordedData of cfg's files (data.path, data.validation_path), read here."""
    return TrainingRecords.read(cfg.path, cfg.validation_path or None).split(cfg)


def recorded_data(cfg: DataConfig, given: TrainingRecords | None = None) -> RecordedData:
    """RecordedData of cfg's split: of the records `given` (in memory), else of cfg's files, read once per
    file version and split (callers must not modify it)."""
    if given is not None:
        return given.split(cfg)
    files = tuple(_file_key(p) for p in (cfg.path, cfg.validation_path) if p)
    split = (cfg.validation_fraction, cfg.split_seed, cfg.split, cfg.validation_path)
    return _recorded(files, cfg.path, split)


def _file_key(path: str) -> tuple:
    p = Path(path)
    stat = p.stat() if p.is_file() else None
    return os.path.abspath(p), stat and (stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=2)
def _recorded(files: tuple, path: str, split: tuple) -> RecordedData:
    fraction, seed, how, validation_path = split
    return read_recorded(
        DataConfig(
            path=path,
            validation_fraction=fraction,
            split_seed=seed,
            split=how,
            validation_path=validation_path,
        )
    )
