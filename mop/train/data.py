"""Training and validation batches: inputs z_0..z_{T-1} (B, T, d_in), targets y_1..y_T (B, T, m).

num_source_systems = M > 0 draws M systems with one trajectory each once (on the training device) and samples
batches from them with a seeded generator; M = 0 draws fresh systems every batch. All training randomness
comes from one torch.Generator (saved in every checkpoint), so the same seed gives the same weights.

Recorded data (config.data, `mop train --data FILE`): mop.train.records splits the file (by trajectory, in
time, or against a separate validation file) and fits per-channel mean/std on the training part; TrainingData
samples windows of train.horizon + 1 steps uniformly over all valid (part, start) pairs of the normalised
training parts; num_source_systems is unused (the file fixes the systems).

Validation on a record split in time or a validation record, for a model that simulates across a gap and
is trained for it (validates_tails): a free-run simulation (each held-out tail after the recorded steps
before it; each validation window from step train.simulate_after on).

Missing outputs: with train.missing_rate / missing_burst_rate / simulate_after > 0 (model.observation_mask)
every batch has outputs dropped at random (with_drop_outs, from the same generator); outputs missing in a
recorded file (NaN) stay missing. Targets then hold NaN where missing and the loss counts only the measured
ones (and the dropped ones with train.score_dropped; the simulated tail of simulate_after always).

train.target = "optimal" (simulated families with a state space, no drop-outs): the training targets are
the one-step predictions of y_1..y_T by the Kalman filter that knows each training system, not y_1..y_T.
Where we differ from the paper (which trains on y_t) on purpose: y_t = yhat_t + e_t with e_t the filter's
innovation, zero-mean given the past and the system, so E||f - y_t||^2 = E||f - yhat_t||^2 + E||e_t||^2
and both losses have the same minimiser over predictors f of the past (the Bayes predictor over the
family, E[yhat_t | y_{<t}, u_{<t}]); the optimal target leaves out the innovation's noise from every
gradient. The validation loss stays against y (the error the experiments measure).
"""

from __future__ import annotations

import dataclasses

import torch
from torch import Tensor

from mop.config import ModelConfig, RunConfig, TrainConfig
from mop.errors import MopError
from mop.filters.linear_gaussian import family_systems, kalman_means
from mop.missing import drop_mask, drop_outputs, masked_inputs
from mop.models.normalization import Normalization
from mop.systems import make_family
from mop.train.context import check_context_prefix, prefix_fit
from mop.train.records import TrainingRecords, recorded_data

NUM_VAL_SYSTEMS = 256


def in_model_units(z: Tensor, y: Tensor, model: ModelConfig) -> tuple[Tensor, Tensor]:
    """Simulated inputs z (B, T, m + k) and targets y (B, T, m) in the model's units (model.output_units /
    input_units, the family's units: Normalization.of_units, the same scaling its predictor reads data
    with; float64), unchanged without them."""
    norm = Normalization.of_units(model)
    return (z, y) if norm is None else (norm.inputs(z), norm.output_units(y.double()))


def simulated_batch(family, num_systems: int, config: RunConfig, generator: torch.Generator) -> tuple:
    """(inputs (B, T, d_in), targets (B, T, m)[, fitted (B, d, m)]) of num_systems fresh systems, in the
    model's units (in_model_units); with train.context_prefix N > 0 each system's first N steps are its
    estimation record (mop.train.context.prefix_fit: the rest in its units, and the feature's coefficients
    fitted on it). train.target = "optimal" (no prefix): the Kalman filter's predictions as targets."""
    cfg, n = config.train, config.train.context_prefix
    traj = family.generate(num_systems, cfg.horizon + n, generator=generator)
    z = traj.model_inputs()  # (B, N + T + 1, d_in)
    if n > 0:
        z, fitted = prefix_fit(z, n, config.model)
        m = config.model.output_dim
        window = (z[:, :-1].float().contiguous(), z[:, 1:, :m].float().contiguous())
        return window if fitted is None else (*window, fitted)
    y = traj.y
    if cfg.target == "optimal":  # (B, T + 1, m): the Kalman filter's predictions of y_t
        y = kalman_means(family_systems(family, traj.params, 0), traj.y, traj.u)
    z, y = in_model_units(z, y, config.model)
    return z[:, :-1].float().contiguous(), y[:, 1:].float().contiguous()


class TrainingData:
    """Batches of (inputs (B, T, d_in), targets (B, T, m)[, fitted (B, d, m) with train.context_prefix]) on
    `device`, all randomness from one generator; simulated ones in the model's units (in_model_units).
    records: the recorded data of config.data in memory (None: read from data.path)."""

    def __init__(
        self, config: RunConfig, device: torch.device, records: TrainingRecords | None = None
    ) -> None:
        check_context_prefix(config)
        self.config = config
        self.cfg = config.train
        self.masked = config.model.observation_mask
        self.generator = torch.Generator(device=device).manual_seed(self.cfg.seed)
        self.pool: tuple | None = None
        if config.data is not None and self.cfg.target == "optimal":
            raise MopError(
                "train.target=optimal trains against the Kalman filter of each simulated system; recorded "
                "data has no known system: use train.target=outputs with --data"
            )
        if config.data is not None:
            self.family = None
            self.windows = recorded_data(config.data, records).windows(config.data, self.cfg.horizon, device)
            return
        self.family = make_family(config.system)
        if self.cfg.target == "optimal":  # refuse a family without a linear-Gaussian model before step 1
            probe = self.family.sample(1, generator=torch.Generator(device=device).manual_seed(0))
            family_systems(self.family, probe, self.cfg.horizon)
        if self.cfg.num_source_systems > 0:  # (M, T, d_in), (M, T, m)[, (M, d, m)]
            self.pool = simulated_batch(self.family, self.cfg.num_source_systems, config, self.generator)

    def batch(self) -> tuple[Tensor, ...]:
        """(inputs (B, T, d_in), targets (B, T, m)[, fitted (B, d, m)]); with train.context_prefix_share < 1
        that share of the batches carries fitted, the others not (drawn per batch); with a model that has an
        observation mask, targets hold NaN where an output is missing (dropped here, or missing in the data)
        and inputs the mask layout."""
        inputs, targets, *fitted = self._clean_batch()
        share = self.cfg.context_prefix_share
        if fitted and share < 1:  # this batch reads its windows alone (no estimation record's fit)
            if torch.rand((), generator=self.generator, device=self.generator.device) >= share:
                fitted = []
        if self.masked:
            inputs, targets = with_drop_outs(inputs, targets, self.cfg, self.generator)
        return (inputs, targets, *fitted)

    def _clean_batch(self) -> tuple[Tensor, ...]:
        if self.family is None:
            return self.windows.sample(self.cfg.batch_size, self.generator)
        if self.pool is None:
            return simulated_batch(self.family, self.cfg.batch_size, self.config, self.generator)
        index = torch.randint(
            0,
            self.pool[0].shape[0],
            (self.cfg.batch_size,),
            generator=self.generator,
            device=self.generator.device,
        )
        return tuple(a[index] for a in self.pool)


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
    tail = simulated_tail(clean.shape, cfg.simulate_after, generator)  # (B, T+1, 1)
    y = drop_outputs(clean, drop | tail)
    z = torch.cat([y[:, :-1], inputs[..., m:]], dim=-1)
    scored = clean if cfg.score_dropped else torch.where(tail.to(y.device), clean, y)
    return masked_inputs(z, m), scored[:, 1:].contiguous()


def simulated_tail(shape: torch.Size, after: int, generator: torch.Generator) -> Tensor:
    """(B, T+1, 1) bool: True from step s on, s ~ U{after..T} per trajectory (train.simulate_after = c > 0;
    all False for 0): the outputs a free-run simulation from s predicts from the inputs alone, dropped and
    scored (a model with forecast_mode = "gap" simulates by reading them as missing)."""
    B, T1 = shape[0], shape[1]
    dev = generator.device
    if after <= 0:
        return torch.zeros(B, T1, 1, dtype=torch.bool, device=dev)
    start = torch.randint(after, T1, (B, 1), generator=generator, device=dev)  # (B, 1)
    return (torch.arange(T1, device=dev)[None, :] >= start)[..., None]


def validates_tails(config: RunConfig, records: TrainingRecords | None = None) -> bool:
    """True where the validation loss is a free-run simulation: on recorded data split in time or given a
    validation record, for a model that simulates across a gap of outputs (model.forecast_mode = "gap")
    and is trained for it (train.simulate_after > 0), so train.keep_best keeps the weights that simulate
    best. Split in time: each held-out tail after the steps before it; a validation record: each of its
    validation windows from step train.simulate_after on (validation_batch)."""
    if config.data is None or config.model.forecast_mode != "gap" or config.train.simulate_after <= 0:
        return False
    return recorded_data(config.data, records).split in ("time", "file")


def tail_batch(windows: Tensor, cuts: Tensor, output_dim: int) -> tuple[Tensor, Tensor]:
    """Windows (N, T+1, m + k) [y, u] and cuts (N,) -> (masked inputs (N, T, m + k + m) with y_s missing
    from s = cut on, targets (N, T, m) = y_1..y_T where s >= cut, NaN before): the loss is the MSE of the
    gap simulation of y_cut..y_T from the steps before and the inputs."""
    m = output_dim
    steps = torch.arange(windows.shape[1], device=windows.device)[None, :, None]  # (1, T+1, 1)
    tail = steps >= cuts.to(windows.device)[:, None, None]  # (N, T+1, 1)
    y = drop_outputs(windows[..., :m], tail)
    z = torch.cat([y[:, :-1], windows[:, :-1, m:]], dim=-1)
    scored = torch.where(tail, windows[..., :m], torch.full_like(windows[..., :m], float("nan")))
    return masked_inputs(z, m), scored[:, 1:].contiguous()


def validation_batch(
    config: RunConfig, device: torch.device, records: TrainingRecords | None = None
) -> tuple[Tensor, ...]:
    """Held-out systems (a generator seeded apart from training) for the validation loss.

    Recorded data: the validation windows of mop.train.records (RecordedData.validation_windows); where
    validates_tails, the held-out tails after the steps before them (RecordedData.tail_windows, tail_batch);
    of `records` in memory where given, else of data.path.
    """
    g = torch.Generator(device=device).manual_seed(config.train.seed + 1_000_003)
    if validates_tails(config, records):
        cfg, data = config.train, recorded_data(config.data, records)
        if data.split == "time":
            windows, cuts = data.tail_windows(config.data, cfg.horizon, cfg.simulate_after)
        else:
            windows = data.validation_steps(config.data, cfg.horizon)
            cuts = torch.full((windows.shape[0],), min(cfg.simulate_after, cfg.horizon), dtype=torch.long)
        return tail_batch(windows.to(device), cuts, config.model.output_dim)
    if config.data is not None:
        val = recorded_data(config.data, records).validation(config.data, config.train.horizon, device)
    else:  # (N, T, d_in), (N, T, m)[, (N, d, m)], against the outputs themselves
        outputs = dataclasses.replace(config, train=dataclasses.replace(config.train, target="outputs"))
        val = simulated_batch(make_family(config.system), NUM_VAL_SYSTEMS, outputs, g)
    if config.model.observation_mask:  # the same kind of drop-outs as in training, seeded apart
        return (*with_drop_outs(val[0], val[1], config.train, g), *val[2:])
    return val
