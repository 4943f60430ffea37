"""The learned model's feature front end: what it reads besides the network's body and read-out.

The front end is the identifier whose one-step prediction the network corrects (the RLS / ARX feature,
its orders, prior and cubes), the scaling of what the network reads (a running input scale, record_norm's
causal moments, the family's units, the correction's scale) and the observation mask. Its keys are model.*
keys (model.rls_order=4 on the command line, in an experiment file, in a run's config.json): ModelConfig
holds them flat, so every saved config and its identity stay as they were, and ModelConfig.front_end gives
them as this section, whose __post_init__ checks them and the knobs among them that need another.
"""

from __future__ import annotations

import dataclasses

from mop.errors import check, check_choice, check_int

FEATURE_CHOICES: dict[str, tuple[str, ...]] = {
    "input_scale": ("none", "running"),
    "features": ("given", "auto"),
    "record_norm": ("none", "causal"),
    "record_moments": ("measured", "filled"),
    "residual_scale": ("none", "running", "measured"),
}


@dataclasses.dataclass(frozen=True)
class FeatureConfig:
    """The feature front end of the learned model (model.* keys; see the module docstring)."""

    input_scale: str = "none"  # "none" or "running": causal per-trajectory scale (mop.models.features)
    record_norm: str = "none"  # "causal": each channel by its running mean and std (mop.models.recordnorm)
    # "running" (with record_norm and the RLS / ARX feature): the network's correction to the feature is
    # scaled by the feature's own recent one-step error, not by the record's std (mop.models.features);
    # "measured": so only at positions whose output is measured, the record's std across gaps
    residual_scale: str = "none"
    # record_norm's output moments over the measured outputs ("measured"), or over the outputs with each
    # missing one filled in by the feature's prediction of it ("filled": a record simulated from its first
    # steps has a scale from step 1, where "measured" has std 0 and mutes the network; needs the feature
    # and observation_mask). The feature's own frame is the measured steps' either way
    record_moments: str = "measured"
    # record_norm's running moments start from this many pseudo-steps at mean 0 and std 1 in every channel
    # (0: none). A fine-tune on a record sets it (mop.recipe.finetune.with_record_prior): its data are
    # normalised by the estimation record's mean and std, so 0 and 1 are that record's moments, and a record
    # simulated from its start is read at the plant's scale from step 0, where without them its output std
    # is 0 and mutes the network
    record_prior_steps: int = 0
    # with residual_scale: the weight of the feature's one-step error k measured steps back is
    # residual_decay^k (0.5: the last one or two errors; a noisy record wants a longer memory)
    residual_decay: float = 0.5
    rls_order: int = 0  # p > 0: read the RLS-AR(p) one-step prediction, predict the residual (features)
    arx_order: int = 0  # q > 0 (with rls_order p): that feature is ARX(p, q), with q lags of the inputs u
    rls_offset: bool = False  # the RLS / ARX feature has a constant regressor (an intercept; features)
    # c > 0: the feature also regresses on the cubes of its first c output lags, y_t^3..y_{t-c+1}^3 (a
    # cubic NARX, e.g. a Duffing oscillator's stiffness; with record_norm in the feature's frame: features)
    rls_cubes: int = 0
    # the feature's theta_0: "none" (0), "fit" (the ARX fitted on recorded data, by the trainer), "family"
    # (the family's empirical-Bayes prior, mop.train.auto), "mixture" (its mixture of Gaussians,
    # mop.filters.mixture) or the list of coefficients (d rows of m)
    rls_prior: str | list[float] = "none"
    # the feature's P_0 with a list rls_prior: None (1e-3 I, a fitted ARX) or the (d, d) matrix, row-major
    rls_prior_cov: list[float] | None = None
    # a mixture prior (mop.filters.mixture): the K components' weights; rls_prior then holds K blocks of d
    # rows of m, rls_prior_cov K (d, d) matrices, and rls_prior_noise is sigma^2, which weighs them
    rls_prior_weights: list[float] | None = None
    rls_prior_noise: float = 0.0
    # True: the feature's coefficients stay at the listed (or fitted) rls_prior, P_0 = 0: a fixed ARX whose
    # one-step prediction and free run the network corrects, computed at once rather than step by step
    # (the records recipe's long ARX, mop.identify.long_arx: its recursion with P_0 = 1e-3 I cost 0.14 of a
    # 0.17 s training step at ARX(40, 40), batch 64 x 80)
    rls_fixed: bool = False
    # [low_1..low_m, high_1..high_m]: the outputs measured before the record (an estimation record read in
    # context), in the units of a listed rls_prior; the feature's free run is held within their range and
    # the record's own, widened as fill_bounds widens it (mop.filters.rls). None: the record's own alone
    rls_fill_range: list[float] | None = None
    # without a listed rls_prior, the feature's P_0 = rls_p0 I, i.e. a ridge 1 / rls_p0 towards 0 (1: the
    # paper's RLS); larger: closer to least squares, for data a model identifies exactly (no noise)
    rls_p0: float = 1.0
    # the family's units (mop.train.auto.family_units): the model reads y_t / output_units and u_t /
    # input_units (one positive number per channel, m and k; None: as simulated) and its predictions are
    # multiplied back, like a recorded-data run's normalisation (mop.models.normalization, of_units)
    output_units: list[float] | None = None
    input_units: list[float] | None = None
    # "given": input_scale / rls_order / arx_order as set; "auto": chosen from the family's shapes and data,
    # train.steps scaled by the feature's step cost (mop.train.auto; resolved before training, so saved)
    features: str = "given"
    # True: the model reads [y_t zero-filled where missing, u_t, observed_t (0/1 per output)], width
    # m + k + m, and may be given outputs with gaps; the trainer sets it when training drops outputs
    observation_mask: bool = False

    def __post_init__(self) -> None:
        check(self.rls_p0 > 0, f"model.rls_p0 must be > 0 (P_0 = rls_p0 I), got {self.rls_p0}")
        check(
            self.rls_prior_weights is None or self.rls_prior_noise > 0,
            f"model.rls_prior_noise must be > 0 beside model.rls_prior_weights, got {self.rls_prior_noise}",
        )
        for name in ("output_units", "input_units"):
            units = getattr(self, name)
            check(
                units is None or (isinstance(units, list) and all(float(v) > 0 for v in units)),
                f"model.{name} must be a list of positive numbers, one per channel, got {units!r:.60}",
            )
        check(
            0 < self.residual_decay < 1,
            f"model.residual_decay must be in (0, 1) (the error k steps back weighs decay^k), got "
            f"{self.residual_decay}",
        )
        for name, choices in FEATURE_CHOICES.items():
            check_choice(f"model.{name}", getattr(self, name), choices)
        check(
            not self.rls_fixed or (self.rls_prior == "fit" or isinstance(self.rls_prior, list)),
            "model.rls_fixed keeps the feature at its listed coefficients: set model.rls_prior=fit or a list",
        )
        check(
            not (self.rls_fixed and (self.rls_prior_cov is not None or self.rls_prior_weights is not None)),
            "model.rls_fixed sets P_0 = 0: drop model.rls_prior_cov / rls_prior_weights",
        )
        check(
            self.rls_fill_range is None
            or (isinstance(self.rls_fill_range, list) and len(self.rls_fill_range) % 2 == 0),
            "model.rls_fill_range lists each output's low then each one's high, got "
            f"{self.rls_fill_range!r:.60}",
        )
        check_int("model.rls_order", self.rls_order, 0, 40, " (0 = off)")
        check_int("model.arx_order", self.arx_order, 0, 40, " (0 = output-only RLS)")
        check_int("model.rls_cubes", self.rls_cubes, 0, 20, " (0 = linear regressors)")
        for name in ("rls_offset", "observation_mask"):
            check_choice(f"model.{name}", getattr(self, name), (True, False))
        self._check_combinations()

    def _check_combinations(self) -> None:
        """The knobs that need another knob of the front end set."""
        check(
            self.arx_order == 0 or self.rls_order > 0,
            "model.arx_order adds input lags to the RLS feature: set model.rls_order > 0 too",
        )
        check(
            self.rls_cubes <= self.rls_order,
            "model.rls_cubes adds the cubes of the RLS feature's first output lags: "
            "keep it <= model.rls_order",
        )
        check(
            not self.rls_offset or self.rls_order > 0,
            "model.rls_offset adds a constant to the RLS feature: set model.rls_order > 0 too",
        )
        check(
            self.residual_scale == "none" or (self.record_norm == "causal" and self.rls_order > 0),
            "model.residual_scale scales the correction to the RLS / ARX feature by that feature's recent "
            "error: set model.record_norm=causal and model.rls_order > 0 too",
        )
        check(
            self.record_moments == "measured"
            or (self.record_norm == "causal" and self.rls_order > 0 and self.observation_mask),
            "model.record_moments='filled' fills missing outputs with the RLS / ARX feature's predictions: "
            "set model.record_norm=causal, model.rls_order > 0 and model.observation_mask=true too",
        )
        check(
            self.record_prior_steps == 0 or (self.record_norm == "causal" and self.record_prior_steps > 0),
            "model.record_prior_steps starts record_norm's running moments from pseudo-steps: set "
            "model.record_norm=causal too, and a count >= 0",
        )


# the front end's keys, in the order FeatureConfig declares them
FEATURE_CONFIG_KEYS: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(FeatureConfig))
