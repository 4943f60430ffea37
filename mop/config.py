"""Config dataclasses and the machinery shared by all of them.

Each config validates itself in __post_init__ with a MopError naming the bad value.
`from_dict` refuses unknown keys; `apply_overrides` takes dotted `key=value` strings
(e.g. "model.num_layers=4", "train.steps=200") as a config file or the CLI gives them.
"""

from __future__ import annotations

import dataclasses
import typing
from typing import Any, TypeVar

from mop.errors import MopError, check, check_choice, check_int  # noqa: F401  (check: re-exported)
from mop.feature_config import FEATURE_CHOICES, FEATURE_CONFIG_KEYS, FeatureConfig
from mop.identity import identity
from mop.network_config import NETWORK_KEYS, NetworkConfig, network_config_class
from mop.systems.base import SystemConfig, config_class
from mop.typecheck import dataclass_type, parse_value, type_matches, type_words

T = TypeVar("T")


def from_dict(cls: type[T], data: dict[str, Any], where: str = "") -> T:
    """Build dataclass `cls` from a (possibly nested) dict, refusing unknown keys."""
    if not isinstance(data, dict):
        raise MopError(f"config{where and ' ' + where} must be a mapping, got {type(data).__name__}")
    cls = cls.resolve_class(data) if hasattr(cls, "resolve_class") else cls  # a family's own config
    fields = {f.name: f for f in dataclasses.fields(cls)}
    hints = typing.get_type_hints(cls)
    unknown = sorted(set(data) - set(fields))
    if unknown:
        keys, known = ", ".join(repr(where + k) for k in unknown), ", ".join(fields)
        raise MopError(f"unknown config key{'s' * (len(unknown) > 1)} {keys}; known keys: {known}")
    kwargs = {}
    for name, value in data.items():
        sub = dataclass_type(hints[name])
        if sub and isinstance(value, dict):
            value = from_dict(sub, value, f"{where}{name}.")
        elif not type_matches(value, hints[name]):
            raise MopError(f"{where}{name} must be {type_words(hints[name])}, got {value!r}")
        kwargs[name] = value
    try:
        return cls(**kwargs)
    except TypeError as err:
        raise MopError(f"bad config{where and ' ' + where}: {err}") from None


def to_dict(config: Any, omit_defaults: bool = True) -> dict[str, Any]:
    """The config as nested dicts; a RunConfig's is its identity (mop.identity: config.json, the run hash),
    or with omit_defaults=False every key (and no "data" key without recorded data)."""
    if isinstance(config, RunConfig) and omit_defaults:
        return identity(config)
    data = dataclasses.asdict(config)
    if isinstance(config, RunConfig) and config.data is None:
        del data["data"]
    return data


def parse_overrides(overrides: list[str]) -> dict[str, Any]:
    """Dotted `key=value` strings (the command line's) -> {key: value}, values parsed as JSON where possible,
    else kept as strings; a key given twice keeps its last value."""
    settings = {}
    for item in overrides:
        if "=" not in item:
            raise MopError(f"override {item!r} is not key=value (e.g. train.steps=200)")
        key, raw = item.split("=", 1)
        settings[key] = parse_value(raw)
    return settings


def apply_overrides(config: T, overrides: list[str]) -> T:
    """Return a copy of `config` with dotted `key=value` overrides applied (apply_settings)."""
    return apply_settings(config, parse_overrides(overrides))


def apply_settings(config: T, settings: dict[str, Any]) -> T:
    """Return a copy of `config` with {dotted key: value} applied, e.g. {"train.steps": 200}.

    A `family` setting is applied first and keeps only the knobs the new family's config also has
    (system.family=quadrotor drops spectral_radius).
    """
    data = to_dict(config, omit_defaults=False)
    for key, value in sorted(settings.items(), key=lambda item: item[0].split(".")[-1] != "family"):
        node = data
        *path, leaf = key.split(".")
        if path[:1] == ["data"] and "data" not in data:
            raise MopError(f"override {key!r} needs recorded data: give `mop train --data FILE`")
        for part in path:
            if not isinstance(node.get(part), dict):
                raise MopError(f"unknown config key {key!r}")
            node = node[part]
        if leaf not in node:
            raise MopError(f"unknown config key {key!r}; known keys here: {', '.join(node)}")
        if leaf == "family" and value != node["family"]:
            _change_family(node, value)
        if value is None and "none" in NAMED_NONE.get(".".join(path), {}).get(leaf, ()):
            value = "none"  # model.record_norm=none: the choice named "none", which parse_value reads as null
        node[leaf] = value
    base = SystemConfig if isinstance(config, SystemConfig) else type(config)
    return from_dict(base, data)


def _change_family(node: dict[str, Any], family: Any) -> None:
    """Make `node` a config of `family`: drop the knobs it lacks, add its new ones, and give the knobs both
    families have the new family's default unless they were changed from the old family's default (so
    system.family=pendulum runs the pendulum's own noise, while a noise level set before stays)."""
    defaults = dataclasses.asdict(config_class(str(family))())
    try:
        before = dataclasses.asdict(config_class(str(node.get("family")))())
    except MopError:  # the old family is unknown: keep what is there
        before = {}
    for key in [k for k in node if k not in defaults]:
        del node[key]
    for key, value in defaults.items():
        if key not in node or (key in before and node[key] == before[key]):
            node[key] = value


MODEL_CHOICES: dict[str, tuple[str, ...]] = {
    "readout": ("mean", "gaussian"),
    "position": ("learned", "rope"),
    "forecast_mode": ("rollout", "gap", "direct"),
    "horizon_loss": ("mean", "balanced"),
    "gap_loss": ("pooled", "balanced"),
}


@dataclasses.dataclass(frozen=True)
class ModelConfig:
    """The learned predictor. input_dim / output_dim of 0 mean "take them from the system family".

    Its keys come in three groups: the network (arch .. position: model.arch names the architecture, and
    network gives the keys it reads as its section, mop.network_config, which checks them), the feature
    front end (input_scale .. observation_mask: FeatureConfig's keys, mop.feature_config, which documents
    and checks them; front_end gives them as that section), and the multi-step read-out (forecast_mode ..
    gap_loss). All are held flat here, so model.width=128 and model.rls_order=4 and every saved
    config.json read as before.
    """

    # a name in mop.models' registry: "gpt" (the paper's GPT-2 body), "gru" (baseline), "deep-lru"
    arch: str = "gpt"
    num_layers: int = 12  # transformer blocks (the paper's 12)
    num_heads: int = 8  # attention heads per block; must divide width
    width: int = 256  # embedding width d_model (the paper's 256)
    context: int = 50  # maximum positions the model attends over (the paper's T)
    input_dim: int = 0  # channels the model reads per step; 0: from the family (m + k, + m with a mask)
    output_dim: int = 0  # outputs it predicts per step; 0: the family's m
    readout: str = "mean"  # "mean" (MSE) or "gaussian" (mean and variance, NLL)
    dropout: float = 0.0  # dropout rate in the transformer body (the paper's 0)
    position: str = "learned"  # "learned" (GPT-2 absolute, the paper) or "rope" (rotary; exact streaming)
    # the feature front end, FeatureConfig's keys in its order (defaults and meanings are FeatureConfig's)
    input_scale: str = FeatureConfig.input_scale
    record_norm: str = FeatureConfig.record_norm
    residual_scale: str = FeatureConfig.residual_scale
    record_moments: str = FeatureConfig.record_moments
    record_prior_steps: int = FeatureConfig.record_prior_steps
    residual_decay: float = FeatureConfig.residual_decay
    rls_order: int = FeatureConfig.rls_order
    arx_order: int = FeatureConfig.arx_order
    rls_offset: bool = FeatureConfig.rls_offset
    rls_cubes: int = FeatureConfig.rls_cubes
    rls_prior: str | list[float] = FeatureConfig.rls_prior
    rls_prior_cov: list[float] | None = FeatureConfig.rls_prior_cov
    rls_prior_weights: list[float] | None = FeatureConfig.rls_prior_weights
    rls_prior_noise: float = FeatureConfig.rls_prior_noise
    rls_fixed: bool = FeatureConfig.rls_fixed
    rls_fill_range: list[float] | None = FeatureConfig.rls_fill_range
    rls_p0: float = FeatureConfig.rls_p0
    output_units: list[float] | None = FeatureConfig.output_units
    input_units: list[float] | None = FeatureConfig.input_units
    features: str = FeatureConfig.features
    observation_mask: bool = FeatureConfig.observation_mask
    # k-step forecasts (mop.models.predictor.LearnedPredictor.forecast): "rollout" feeds the model its own
    # predictions; "gap" (needs observation_mask) reads the future outputs as missing, with the given inputs;
    # "direct" reads the k-step heads (model.horizons = K > 1; steps <= K, systems without inputs u)
    forecast_mode: str = "rollout"
    # K > 1: K read-out heads, head k predicting y_{t+k} from the inputs up to t, trained by the mean of their
    # losses (mop.models.heads); 1: the paper's one-step read-out
    horizons: int = 1
    # how the heads' losses combine: "mean", or "balanced" (each head's gradient scaled by 1 / its loss)
    horizon_loss: str = "mean"
    # with model.observation_mask, how the one-step loss weighs the positions that read a missing output
    # (the steps of a simulated tail, train.simulate_after) against those that read a measured one:
    # "pooled" (every scored entry alike) or "balanced" (the geometric mean of the two groups' MSEs, so a
    # 1% gain one step ahead counts as much as 1% in simulation; mop.models.heads.prediction_loss)
    gap_loss: str = "pooled"

    @property
    def front_end(self) -> FeatureConfig:
        """The feature front end's keys as their own section."""
        return FeatureConfig(**{key: getattr(self, key) for key in FEATURE_CONFIG_KEYS})

    @property
    def network(self) -> NetworkConfig:
        """The network keys model.arch reads, as that architecture's section (mop.network_config; an
        architecture without one of its own gets the generic section, every network key)."""
        return network_config_class(self.arch).of(self)

    def __post_init__(self) -> None:
        # the known architectures live in mop.models' registry; build_model and the trainer check them
        check(isinstance(self.arch, str) and self.arch != "", f"model.arch must be a name, got {self.arch!r}")
        self.network  # noqa: B018  (the architecture's section checks the network's keys when built)
        for name, choices in MODEL_CHOICES.items():
            if name not in NETWORK_KEYS:  # the network's choices: its section's
                check_choice(f"model.{name}", getattr(self, name), choices)
        check_int("model.horizons", self.horizons, 1, 100, " (1 = the one-step read-out)")
        self.front_end  # noqa: B018  (FeatureConfig checks the front end's keys when built)
        self._check_combinations()

    def _check_combinations(self) -> None:
        """The read-out's knobs that need another knob set (the front end's own: FeatureConfig)."""
        check(
            self.horizon_loss == "mean" or self.readout == "mean",
            "model.horizon_loss='balanced' divides by each head's loss, which a Gaussian read-out's NLL "
            "can make zero or negative; use model.readout='mean'",
        )
        check(
            self.gap_loss == "pooled" or (self.observation_mask and self.readout == "mean"),
            "model.gap_loss='balanced' weighs positions that read a missing output against those that read "
            "a measured one by their MSEs: set model.observation_mask=true and model.readout='mean'",
        )
        check(
            self.forecast_mode != "direct" or self.horizons > 1,
            "model.forecast_mode='direct' reads the k-step heads: set model.horizons=K > 1 "
            "(forecasts of up to K steps)",
        )
        check(
            self.forecast_mode != "gap" or self.observation_mask,
            "model.forecast_mode='gap' reads future outputs as missing: it needs model.observation_mask=true "
            "(train with train.missing_burst_rate > 0, and train.score_dropped=true to learn the gaps)",
        )


TRAIN_CHOICES: dict[str, tuple[str, ...]] = {
    "lr_schedule": ("constant", "cosine"),
    "precision": ("auto", "fp32", "bf16"),
    "compile": ("auto", "on", "off", "graphs"),
    "target": ("outputs", "optimal"),
}


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """The paper's optimizer settings are the defaults (AdamW 3e-4, wd 0.01, clip 1.0, batch 64, 10000 steps).

    num_source_systems: M, systems with one trajectory each, drawn once; 0 = fresh systems every batch.
    horizon: T, training trajectories hold y_0..y_T; the model reads y_0..y_{T-1} and predicts y_1..y_T.
    missing_rate: fraction of training outputs dropped at random, independently per channel and step
        (mop.missing.drop_outputs); with missing_burst_rate (the chance per step that a burst of
        missing_burst_length steps with every channel missing starts there) > 0 too, the model gets an
        observation mask channel (model.observation_mask) and the loss counts only the measured targets.
    score_dropped: the loss also scores the outputs training dropped (it knows them), so the model learns to
        predict across a gap of missing outputs: with bursts, a multi-step forecast loss (for
        model.forecast_mode = "gap"). Outputs missing in recorded data stay unscored.
    """

    steps: int = 10000  # optimizer steps (a preset's budget is in plain-model steps, model.features)
    batch_size: int = 64  # trajectories per step
    lr: float = 3e-4  # AdamW learning rate (the peak, with warm-up and a schedule)
    weight_decay: float = 0.01  # AdamW weight decay
    grad_clip: float = 1.0  # gradients clipped to this global norm
    lr_schedule: str = "constant"  # "constant" or "cosine"
    warmup_steps: int = 0  # linear learning-rate warm-up from 0 over this many steps
    num_source_systems: int = 20000
    horizon: int = 50
    seed: int = 0  # training seed: initial weights, systems drawn, batches
    device: str = "auto"  # "auto", "cpu", "cuda", "cuda:1", ...
    precision: str = "auto"  # "auto" (bf16 on GPU, fp32 on CPU), "fp32", "bf16"
    compile: str = "auto"  # "auto", "on", "off", "graphs" (on, with CUDA graphs: mode reduce-overhead)
    log_every: int = 50  # steps between logged training losses (the run's log, the progress bar)
    checkpoint_every: int = 1000  # steps between checkpoints (validation loss, state to resume from)
    deterministic: bool = False  # torch.use_deterministic_algorithms (slower on GPU)
    missing_rate: float = 0.0
    missing_burst_rate: float = 0.0  # chance per step that a burst of missing outputs starts there
    missing_burst_length: int = 5  # steps of each burst (every channel missing)
    score_dropped: bool = False
    simulate_after: int = 0  # c > 0: y_s.. dropped and scored, s ~ U{c..T}: a simulation loss (data.py)
    # c > 0: the loss is each window's free run after its first c outputs, the predictions fed back
    # (mop.train.rollout_loss), for the last rollout_share of the steps; the steps before, one step ahead
    rollout_after: int = 0
    rollout_share: float = 1.0
    init: str = ""  # a run directory or pretrained:NAME whose weights step 0 starts from (mop.recipe.source)
    # True: model.safetensors holds the weights of the lowest validation loss, step 0's included (so a model
    # that starts as its feature ends no worse than it on the validation systems), not the last (loop.py)
    keep_best: bool = False
    # True: after training, the network's correction (the read-out) is scaled by the gain that simulates the
    # records of data.path best from their start; a fine-tuned class model's default (mop.recipe.shrink)
    shrink_correction: bool = False
    # what the one-step loss compares the prediction of y_t with: "outputs", y_t itself (the paper's), or
    # "optimal", the prediction of y_t by the Kalman filter that knows the training system (data.py)
    target: str = "outputs"
    # N > 0: every training system's first N steps are its estimation record, on which the class model's
    # feature is fitted before the window the network reads (mop.train.context); 0: none
    context_prefix: int = 0
    # with context_prefix: the share of training batches that read their estimation record's fit; the others
    # read their windows alone, the feature identified from each window's own outputs (as without a record)
    context_prefix_share: float = 1.0

    @property
    def drops_outputs(self) -> bool:
        """True when training drops outputs (so the model needs the observation mask)."""
        return self.missing_rate > 0 or self.missing_burst_rate > 0 or self.simulate_after > 0

    def __post_init__(self) -> None:
        for name in ("missing_rate", "missing_burst_rate"):
            value = getattr(self, name)
            check(
                isinstance(value, (int, float)) and 0 <= value < 1,
                f"train.{name} must be in [0, 1), got {value!r}",
            )
        check(
            isinstance(self.score_dropped, bool) and (self.drops_outputs or not self.score_dropped),
            "train.score_dropped=true scores the outputs training drops: it needs train.missing_rate or "
            f"train.missing_burst_rate > 0 (got score_dropped={self.score_dropped!r})",
        )
        for name in "steps batch_size horizon log_every checkpoint_every missing_burst_length".split():
            check_int(f"train.{name}", getattr(self, name), 1)
        check_int("train.simulate_after", self.simulate_after, 0, self.horizon, " (at most train.horizon)")
        check_int("train.context_prefix", self.context_prefix, 0)
        check_int("train.rollout_after", self.rollout_after, 0, self.horizon - 1, " (below train.horizon)")
        check(
            isinstance(self.rollout_share, (int, float)) and 0 < self.rollout_share <= 1,
            f"train.rollout_share must be in (0, 1], got {self.rollout_share!r}",
        )
        check(
            isinstance(self.context_prefix_share, (int, float)) and 0 < self.context_prefix_share <= 1,
            f"train.context_prefix_share must be in (0, 1], got {self.context_prefix_share!r}",
        )
        check(
            self.num_source_systems >= 0,
            f"train.num_source_systems must be >= 0, got {self.num_source_systems}",
        )
        check(self.lr > 0, f"train.lr must be > 0, got {self.lr}")
        check(
            self.weight_decay >= 0 and self.grad_clip > 0, "train.weight_decay must be >= 0 and grad_clip > 0"
        )
        for name, choices in TRAIN_CHOICES.items():
            check_choice(f"train.{name}", getattr(self, name), choices)
        check(
            self.target == "outputs" or not self.drops_outputs,
            "train.target=optimal scores one-step predictions against the Kalman filter's; it does not "
            "combine with dropped outputs (missing_rate, missing_burst_rate, simulate_after): use "
            "train.target=outputs",
        )


FEATURE_RUN = "free-run"  # data.feature_input: the network reads its least-squares feature's free run
DATA_CHOICES: dict[str, tuple[str, ...]] = {
    "split": ("auto", "trajectory", "time"),
    "feature_input": ("none", FEATURE_RUN),
}


@dataclasses.dataclass(frozen=True)
class DataConfig:
    """Recorded trajectories to train on (`mop train --data FILE`) instead of simulating `system`.

    path: a .npz (y (B, T+1, m), optional u (B, T+1, k)) or the long CSV that `mop predict` reads; one
        trajectory per system, lengths may differ (those shorter than train.horizon + 1 outputs are skipped).
    validation_fraction: share held out for the validation loss: of the trajectories (split "trajectory",
        a permutation seeded by split_seed) or of each trajectory's last steps (split "time").
    split: "auto" (by trajectory where that leaves one on each side, else in time: mop.train.records),
        "trajectory" or "time"; unused with validation_path.
    validation_path: a separate validation record (`mop train --val FILE`); every step of path then trains.
    feature_input: "none", or "free-run" (FEATURE_RUN): the network reads the records recipe's
        least-squares feature's free run as m more inputs and predicts what it leaves
        (mop.models.feature_input); the run holds that feature (RUN/feature). The records recipe's deep
        LRU reads it by default.
    y_mean, y_std (m values each), u_mean, u_std (k values each, [] without inputs): per-channel
        normalisation in the file's units, fitted on the training split by the trainer (None = not yet
        fitted; a given value must equal the fit). The predictor of the run applies it, so predictions come
        back in the file's units.
    """

    path: str = ""
    validation_fraction: float = 0.1
    split_seed: int = 0  # seed of the permutation that picks the validation trajectories
    split: str = "auto"
    validation_path: str = ""
    feature_input: str = "none"
    y_mean: list[float] | None = None
    y_std: list[float] | None = None
    u_mean: list[float] | None = None
    u_std: list[float] | None = None

    def __post_init__(self) -> None:
        check(isinstance(self.path, str) and self.path != "", "data.path must name a .npz or .csv file")
        check(
            isinstance(self.validation_fraction, (int, float)) and 0 < self.validation_fraction < 1,
            f"data.validation_fraction must be in (0, 1), got {self.validation_fraction!r}",
        )
        check(isinstance(self.split_seed, int), f"data.split_seed must be an integer: {self.split_seed!r}")
        for name, choices in DATA_CHOICES.items():
            check_choice(f"data.{name}", getattr(self, name), choices)
        check(isinstance(self.validation_path, str), "data.validation_path must name a .npz or .csv file")
        for name in ("y_std", "u_std"):
            value = getattr(self, name)
            check(
                value is None or all(isinstance(s, (int, float)) and s > 0 for s in value),
                f"data.{name} must hold positive numbers, got {value!r}",
            )

    @property
    def reads_feature_run(self) -> bool:
        """Whether the network reads its least-squares feature's free run (feature_input = FEATURE_RUN)."""
        return self.feature_input == FEATURE_RUN

    @property
    def fitted(self) -> bool:
        return None not in (self.y_mean, self.y_std, self.u_mean, self.u_std)


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """Everything `mop train` needs; saved as config.json in the run directory.

    Enough on its own to rebuild the model (and, for recorded data, its normalisation).
    data: None trains on simulated systems of `system` (and is left out of config.json, so runs without
    data keep their config and its hash); a DataConfig trains on recorded trajectories (`system` unused).
    """

    system: SystemConfig = dataclasses.field(default_factory=SystemConfig)
    model: ModelConfig = dataclasses.field(default_factory=ModelConfig)
    train: TrainConfig = dataclasses.field(default_factory=TrainConfig)
    data: DataConfig | None = None


# the sections whose choices may be named "none", which a key=value override's JSON reads as null
NAMED_NONE: dict[str, dict[str, tuple[str, ...]]] = {"model": FEATURE_CHOICES, "data": DATA_CHOICES}
