"""An experiment is data: what to train, where to test, which predictors, analyses, figures and claims.

    Experiment(
        name="linear", title="Fig. 2a",
        train={"system.family": "linear"},                         # RunConfig overrides on the preset
        predictors=("mop", "gru", "kalman", "rls"),                 # PREDICTORS names
        conditions=(Condition("test"),),                            # test settings (sweeps: several)
        claims=(Claim("MOP matches the KF after ~20 steps", Measure("mse_ratio", window=(20, None)),
                      "<=", 1.05),),
    )

One generic runner (mop.experiments.runner) executes any of them; `mop reproduce FILE.toml` reads the same
fields from a TOML or JSON file (mop.experiments.files), so a user writes an experiment without Python.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from mop.config import check
from mop.predictors import PREDICTORS, is_learned

MISSING_KEYS = ("rate", "burst_rate", "burst_length")
OPERATORS = ("<", "<=", ">", ">=", "between", "contains", "info")


@dataclasses.dataclass(frozen=True)
class Measure:
    """A number (or interval) read from an experiment's results; what a claim compares.

    metric: a name in mop.experiments.measures.MEASURES, e.g.
        "mse_ratio"  MSE of `predictor` / MSE of `reference` over t in `window` (bound: ratio | low | high,
                     the 95% paired-bootstrap interval ends)
        "mean_error" mean over systems and t in `window` of ||yhat_t - y_t||
        "coverage"   fraction of outputs inside the central `level` interval (predictors with a distribution)
        "matrix_power_max"  max over k of the mean ||A^k|| / rho(A)^k of the test systems
        "slope"      log-log slope of the excess MSE over the conditions of sweep axis `axis` (its 95% CI)
        "simulation_rmse" / "one_step_rmse"  RMSE of `predictor` in free-run simulation after the condition's
                     context / one-step over the same steps (needs the "simulation" analysis)
    window: [start, stop) in time steps; stop None means T + 1.
    condition: the test condition's name; "" the first one; "*" every condition, combined by `reduce`.
    """

    metric: str
    predictor: str = ""  # "" = the first learned predictor of the results (the model the experiment is about)
    reference: str = ""  # "" = the experiment's reference
    window: tuple[int, int | None] = (20, None)
    condition: str = ""
    reduce: str = "max"  # with condition "*": max | min
    bound: str = "ratio"
    level: float = 0.9
    axis: str = ""

    def __post_init__(self) -> None:
        for name in ("metric", "predictor", "reference", "condition", "axis"):
            value = getattr(self, name)
            check(isinstance(value, str), f"measure {name} must be a name (a string), got {value!r}")
        check(
            self.bound in ("ratio", "low", "high"),
            f"measure bound must be ratio|low|high, got {self.bound!r}",
        )
        check(self.reduce in ("max", "min"), f"measure reduce must be max|min, got {self.reduce!r}")
        window = self.window
        check(
            isinstance(window, (tuple, list))
            and len(window) == 2
            and _is_int(window[0])
            and (window[1] is None or _is_int(window[1])),
            f"measure window must be [start, stop) with integer steps (stop may be left out as none), "
            f"got {list(window) if isinstance(window, (tuple, list)) else window!r}",
        )
        start, stop = window
        check(
            start >= 0 and (stop is None or stop > start),
            f"measure window must be [start, stop) with 0 <= start < stop, got {list(self.window)}",
        )
        check(
            _is_number(self.level) and 0 < self.level < 1,
            f"measure level must be a number in (0, 1), got {self.level!r}",
        )


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


@dataclasses.dataclass(frozen=True)
class Claim:
    """A claim of the paper as data: `measure` `op` `threshold`, e.g. MOP/KF ratio t >= 20 <= 1.05.

    threshold: a number, another Measure (compare two results), (low, high) with op "between", or None with
    op "info" (reported, no verdict). op "contains": the measure is an interval that must contain the
    threshold.
    """

    text: str
    measure: Measure
    op: str = "info"
    threshold: float | tuple[float, float] | Measure | None = None

    def __post_init__(self) -> None:
        check(
            self.op in OPERATORS,
            f"claim {self.text!r}: op must be one of {', '.join(OPERATORS)}, got {self.op!r}",
        )
        check(
            self.op == "info" or self.threshold is not None,
            f"claim {self.text!r}: op {self.op!r} needs a threshold",
        )
        check(isinstance(self.measure, Measure), f"claim {self.text!r}: measure must be a Measure table")
        t = self.threshold
        if self.op == "between":
            check(
                isinstance(t, (tuple, list)) and len(t) == 2 and all(map(_is_number, t)) and t[0] <= t[1],
                f"claim {self.text!r}: op 'between' needs threshold [low, high] (numbers, low <= high), "
                f"got {t!r}",
            )
        elif self.op in ("<", "<=", ">", ">="):
            check(
                _is_number(t) or isinstance(t, Measure),
                f"claim {self.text!r}: op {self.op!r} needs a number or a measure as threshold, got {t!r}",
            )
        elif self.op == "contains":
            check(
                _is_number(t),
                f"claim {self.text!r}: op 'contains' needs a number as threshold (the measure is an "
                f"interval), got {t!r}",
            )


@dataclasses.dataclass(frozen=True)
class Condition:
    """One test setting: the test system (overrides of the trained family's config), horizon, and,
    where this condition uses another trained model than the experiment's, its training overrides.

    x: (axis label, value) places the condition on a sweep axis (noise level, M, T) for sweep figures.
    data: a file of recorded test trajectories (.csv / .npz, as `mop predict` reads) used instead of simulated
        systems: every trajectory with at least horizon + 1 outputs, cut to that length; predictors that need
        the system are skipped there.
    missing: outputs of the test trajectories removed before any predictor sees them (mop.missing.drop_mask,
        seeded apart from the systems): {"rate": p} per channel and step, {"burst_rate": q,
        "burst_length": L} whole-step bursts; errors are then measured on the measured outputs only.
    context: the context length c of the "simulation" analysis (free-run simulation of y_c..y_T from the
        inputs alone); None: 4/5 of the horizon (the authors of sysid-transformers: 400 of 500).
    """

    name: str = "test"
    system: dict[str, Any] = dataclasses.field(default_factory=dict)
    horizon: int | None = None  # None: the training horizon
    train: dict[str, Any] = dataclasses.field(default_factory=dict)
    x: tuple[str, float] | None = None
    predictors: tuple[str, ...] = ()  # () = every predictor of the experiment
    data: str = ""
    missing: dict[str, float] = dataclasses.field(default_factory=dict)
    context: int | None = None
    runs: dict[str, str] = dataclasses.field(default_factory=dict)  # as Experiment.runs, for this condition

    def __post_init__(self) -> None:
        check(isinstance(self.name, str) and bool(self.name), "a condition needs a name (a string)")
        check(
            self.horizon is None or (_is_int(self.horizon) and self.horizon >= 1),
            f"condition {self.name}: horizon must be an integer >= 1, got {self.horizon!r}",
        )
        for name in ("system", "train"):
            check(
                isinstance(getattr(self, name), dict),
                f"condition {self.name}: {name} must be a table of key = value overrides, "
                f"got {getattr(self, name)!r}",
            )
        check(
            self.x is None
            or (isinstance(self.x, (tuple, list)) and len(self.x) == 2 and _is_number(self.x[1])),
            f"condition {self.name}: x must be [axis name, number], got {self.x!r}",
        )
        check(
            all(isinstance(p, str) for p in self.predictors),
            f"condition {self.name}: predictors must be a list of names, got {self.predictors!r}",
        )
        check(isinstance(self.data, str), f"condition {self.name}: data must be a file name")
        check(isinstance(self.missing, dict), f"condition {self.name}: missing must be a table")
        check(
            self.context is None or (_is_int(self.context) and self.context >= 1),
            f"condition {self.name}: context must be an integer >= 1, got {self.context!r}",
        )
        unknown = set(self.missing) - set(MISSING_KEYS)
        check(
            not unknown,
            f"condition {self.name}: unknown missing keys {sorted(unknown)}; use {', '.join(MISSING_KEYS)}",
        )
        for key in ("rate", "burst_rate"):
            value = self.missing.get(key, 0.0)
            check(0 <= value < 1, f"condition {self.name}: missing.{key} must be in [0, 1), got {value}")
        length = self.missing.get("burst_length", 5)
        check(
            isinstance(length, int) and length >= 1,
            f"condition {self.name}: missing.burst_length must be an integer >= 1, got {length!r}",
        )


def default_panel(predictors: tuple[str, ...]) -> tuple[str, ...]:
    """The error panel of an experiment that names none: its first learned predictor (the model it is about),
    "" (its reference) and the predictors registered with default_panel=True, e.g. ("mop", "", "rls")."""
    learned = [name for name in predictors if name in PREDICTORS and is_learned(name)][:1]
    return (*learned, "", *PREDICTORS.flagged("default_panel"))


@dataclasses.dataclass(frozen=True)
class Experiment:
    """Everything `mop reproduce NAME` does, as data.

    train: dotted RunConfig overrides applied on top of the preset (e.g. {"system.family": "quadrotor"}).
    presets: per-preset extra training overrides (e.g. a smaller model for a many-run sweep on the CPU).
    predictors: PREDICTORS names; learned ones ("mop", "gru") are trained (or reused) per distinct config.
    reference: the predictor every MSE ratio divides by (the optimal filter where one exists); "" (the
        default) is the predictor registered with default_reference=True (the KF), filled in on construction.
    analyses: names in mop.experiments.analyses.ANALYSES (extra per-condition results, e.g. "floor"); each
        renders its own report table and eval.json entries.
    figures: figure names (mop.experiments.figures); None (the default) draws the figures registered with
        default=True (the error panel; mop.experiments.figures.figure_names), () none.
    panel: predictors of the paper-style panel (error with +-1 std bands); "" stands for the reference.
        None (the default) is filled in on construction: the experiment's first learned predictor, the
        reference and the predictors registered with default_panel=True (RLS).
    runs: learned predictor -> a run directory or `pretrained:NAME` it is loaded from instead of trained,
        e.g. {"mop": "pretrained:linear"} (a condition's `runs` wins over the experiment's).
    best: the best predictor there is for the test systems, which the report measures MOP's distance to:
        the exact optimum where one exists (KF, kalman-colored), else the best filter that knows the system
        (the particle filter on the quadrotor); "" = the reference. The one definition of "best": the
        report's distance (mop.experiments.evaluating) and the pretrained cards both read best_predictor.
    authors: the authors' number to show beside it (text), e.g. "1.025 (their 12 x 256 model, H100)".
    """

    name: str
    title: str
    train: dict[str, Any]
    predictors: tuple[str, ...]
    reference: str = ""
    conditions: tuple[Condition, ...] = (Condition(),)
    claims: tuple[Claim, ...] = ()
    analyses: tuple[str, ...] = ()
    figures: tuple[str, ...] | None = None
    panel: tuple[str, ...] | None = None
    presets: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)
    preset_conditions: dict[str, tuple[Condition, ...]] = dataclasses.field(default_factory=dict)
    description: str = ""
    runs: dict[str, str] = dataclasses.field(default_factory=dict)
    best: str = ""
    authors: str = ""

    @property
    def best_predictor(self) -> str:
        """`best`, or the reference when none is named."""
        return self.best or self.reference

    def conditions_for(self, preset: str) -> tuple[Condition, ...]:
        """The test conditions under `preset` (a sweep may use a smaller grid on a small preset)."""
        return self.preset_conditions.get(preset, self.conditions)

    def __post_init__(self) -> None:
        check(isinstance(self.train, dict), f"experiment {self.name}: train must be a table of overrides")
        for name in ("predictors", "analyses", "figures", "panel"):
            value = getattr(self, name)
            check(
                (value is None and name in ("figures", "panel"))
                or (isinstance(value, (tuple, list)) and all(isinstance(v, str) for v in value)),
                f"experiment {self.name}: {name} must be a list of names, got {value!r}",
            )
        check(isinstance(self.reference, str), f"experiment {self.name}: reference must be a predictor name")
        if not self.reference:  # the defaults are the registered entries' metadata, not names written here
            object.__setattr__(self, "reference", PREDICTORS.default("default_reference"))
        if self.panel is None:
            object.__setattr__(self, "panel", default_panel(self.predictors))
        check(
            all(isinstance(c, Condition) for c in self.conditions),
            f"experiment {self.name}: conditions must be a list of condition tables",
        )
        check(
            all(isinstance(c, Claim) for c in self.claims),
            f"experiment {self.name}: claims must be a list of claim tables",
        )
        check(bool(self.predictors), f"experiment {self.name}: list at least one predictor")
        names = [c.name for c in self.conditions]
        check(len(set(names)) == len(names), f"experiment {self.name}: condition names repeat: {names}")
        check(bool(self.conditions), f"experiment {self.name}: needs at least one condition")
