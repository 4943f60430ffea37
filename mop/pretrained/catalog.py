"""What is shipped: each pretrained model is the MOP of one experiment condition, trained with a preset's
recipe (read from mop.experiments.presets when it is built, so a new recipe is one rebuild away).

    ShippedModel("linear", experiment="linear")   # the run `mop reproduce linear --preset small` trains

The card compares it with that condition's predictors, as `mop reproduce EXPERIMENT --pretrained` does.
"""

from __future__ import annotations

import dataclasses

from mop.errors import MopError


@dataclasses.dataclass(frozen=True)
class ShippedModel:
    """One shipped model: trained as `experiment`'s condition `condition` ("" the first) under `preset`.

    summary: one line for `mop pretrained`; not_for: where the card says not to use it.
    """

    name: str
    experiment: str
    summary: str
    not_for: str
    condition: str = ""
    preset: str = "small"
    seed: int = 0


SHIFT = (
    "noise levels far from training: the card's noise-shift table gives the MOP/KF ratio at other test "
    "noise variances (and `mop reproduce noise-shift` the full sweep for a model trained at 0.1)"
)
LINEAR_DIMS = "systems of another state or output dimension (trained on n = 10 states, m = 5 outputs)"

CATALOG: tuple[ShippedModel, ...] = (
    ShippedModel(
        "linear",
        "linear",
        "dense linear Gaussian systems (the paper's Fig. 2a family); also the model of `switching`",
        f"{LINEAR_DIMS}; {SHIFT}; systems with structure the family lacks (upper-triangular A: use "
        "pretrained:upper-triangular, and even that is worse than RLS); trajectories longer than 50 steps "
        "are predicted in windows of 50 steps starting every 25 (see `mop reproduce switching`)",
    ),
    ShippedModel(
        "linear-gaussian",
        "calibration",
        "dense linear systems with a Gaussian read-out: predictive mean and variance",
        f"{LINEAR_DIMS}; {SHIFT}: the variance is calibrated only near the training noise",
        condition="linear",
    ),
    ShippedModel(
        "colored-noise",
        "colored-noise",
        "linear systems with colored (moving-sum of 5 draws) process and observation noise (Fig. 2b)",
        f"{LINEAR_DIMS}; white-noise systems (use pretrained:linear); {SHIFT}; another noise color window",
    ),
    ShippedModel(
        "upper-triangular",
        "upper-triangular",
        "linear systems with upper-triangular A (Fig. 4): a hard family; with its RLS-AR(3) feature MOP is "
        "below the paper's RLS-AR(2), still far from the KF",
        f"{LINEAR_DIMS}; anywhere accuracy matters: it is far from the KF on this family (see its ratios); "
        f"{SHIFT}",
    ),
    ShippedModel(
        "linear-inputs",
        "linear-inputs",
        "dense linear Gaussian systems driven by 2 known white inputs (x_{t+1} = A x_t + B u_t + w_t)",
        f"{LINEAR_DIMS} and k = 2 inputs; inputs far from u ~ N(0, I) (mop warns when they lie outside the "
        f"training range); {SHIFT}",
    ),
    ShippedModel(
        "quadrotor",
        "quadrotor",
        "planar quadrotors with random mass, arm and inertia, 2 inputs, 3 outputs (Fig. 3)",
        "other vehicles, output maps or input ranges (trained on u ~ U[-0.5, 0.5], 3 outputs of a 6-state "
        f"quadrotor with the authors' state clipping); {SHIFT}",
    ),
)


CLASS = (
    "records of another class, or other input signals than the white N(0, 1) input it was trained on (its "
    "ARX feature and network saw only those spectra), multi-output data (m = 1, k = 1 only), and records "
    "shorter than the ARX order's start-up; fine-tune it on your estimation record (mop train --data FILE "
    "--init pretrained:NAME) where it is not within the card's numbers"
)
CLASS_MODELS: tuple[ShippedModel, ...] = (
    ShippedModel(
        "lti-siso",
        "class-lti-siso",
        "class model of SISO LTI systems of order 1..10 (Forgione et al.'s class), any units (per-record "
        "causal normalisation), trained for free-run simulation: predicts and simulates a new record in "
        "context, zero-shot",
        f"{CLASS}; nonlinear plants (saturation, dead zones): use a nonlinear class",
    ),
    ShippedModel(
        "lti-mimo",
        "class-lti-mimo",
        "class model of LTI systems of order 1..10 with one input and three outputs (the lti-siso class, "
        "mop.systems.lti_mimo: a structure with one shaker and three sensors), any units, trained for "
        "free-run simulation: its feature regresses each output on every output's lags, zero-shot in context",
        "records of another shape (k = 1 input and m = 3 outputs only: use pretrained:lti-siso for one "
        "output), other input signals than the white N(0, 1) input it was trained on, nonlinear plants, and "
        "records shorter than the ARX order's start-up (61 regressors an output); give the estimation record "
        "with --context, or fine-tune it on your estimation record (mop train --data FILE --init "
        "pretrained:lti-mimo)",
    ),
    ShippedModel(
        "wiener-hammerstein",
        "class-wiener-hammerstein",
        "class model of SISO Wiener-Hammerstein systems (linear blocks of order 1..5 around a static tanh "
        "network), any units, trained for free-run simulation: zero-shot in context",
        f"{CLASS}; hard nonlinearities the smooth tanh network lacks (saturation, hysteresis, overflow)",
    ),
    ShippedModel(
        "cascaded-tanks",
        "class-cascaded-tanks",
        "class model of two cascaded water tanks with square-root outflows and overflow (mop.systems."
        "cascaded_tanks: random areas, outflows, pump gain, levels 0..10 V, multisine pump voltage), any "
        "units, trained for free-run simulation: zero-shot in context",
        "records of another class, or inputs unlike a multisine (or noise) about an operating point, "
        "multi-output data (m = 1, k = 1 only), and records shorter than the ARX order's start-up; fine-tune "
        "it on your estimation record (mop train --data FILE --init pretrained:cascaded-tanks) where it is "
        "not within the card's numbers; a real plant's pump and sensor characteristics are not modelled",
    ),
    ShippedModel(
        "duffing",
        "class-duffing",
        "class model of lightly damped oscillators with polynomial stiffness (mop.systems.duffing, the "
        "Silverbox's class), reading the cubic NARX feature, any units, trained for free-run simulation: "
        "zero-shot in context; given an estimation record (mop predict --context) its feature is fitted on "
        "all of it",
        "records of another class (no friction, hysteresis or several modes), multi-output data (m = 1, "
        "k = 1 only), and short contexts: its feature has 31 regressors, so a window of a few hundred steps "
        "identifies it poorly; give the estimation record with --context, or fine-tune it on your estimation "
        "record (mop train --data FILE --init pretrained:duffing)",
    ),
    ShippedModel(
        "duffing-records",
        "class-duffing-records",
        "a start for `mop train --data FILE --init`: the records recipe's 1 x 32 network on its ARX "
        "feature, pretrained on the duffing class with each window read after its estimation record's "
        "least-squares fit, as a fine-tune reads the user's record; fine-tuned with the records recipe's "
        "schedule and budget (on the F-16 8-26% below the records recipe from random weights, three-seed "
        "means)",
        "records read without their estimation record, zero-shot (it predicts worse than the least-squares "
        "ARX then: its card); give it the estimation record (--context) or, better, fine-tune it on it; "
        "records other than one output and one input",
    ),
    ShippedModel(
        "cascaded-tanks-records",
        "class-cascaded-tanks-records",
        "a start for `mop train --data FILE --init`: the records recipe's 1 x 32 network on its ARX(10, 10) "
        "feature, pretrained on two cascaded tanks as measured on the real plant (noise up to 0.02 V, low "
        "process noise, a level sensor saturating below the rim, the pump across its range), each window "
        "read after its estimation record's least-squares fit; fine-tuned with the records recipe's schedule",
        "records read without their estimation record, zero-shot (its card); give it the estimation record "
        "(--context) or fine-tune it on it; records other than one output and one input",
    ),
    ShippedModel(
        "duffing-lru",
        "class-duffing-lru",
        "a start for `mop train --data FILE --init`: the records recipe's own network (the deep LRU, 2 x 32, "
        "no feature) trained on its free-run error on the duffing class, each window read after its "
        "estimation record (in that record's units); fine-tuned with the records recipe's schedule and "
        "budget",
        "records read without their estimation record, zero-shot (its card); fine-tune it on your estimation "
        "record; records other than one output and one input",
    ),
    ShippedModel(
        "cascaded-tanks-lru",
        "class-cascaded-tanks-lru",
        "a start for `mop train --data FILE --init`: the records recipe's own network (the deep LRU, 2 x 32, "
        "no feature) trained on its free-run error on the cascaded tanks as measured on the real plant, each "
        "window read after its estimation record (in that record's units); fine-tuned with the records "
        "recipe's schedule and budget",
        "records read without their estimation record, zero-shot (its card); fine-tune it on your estimation "
        "record; records other than one output and one input",
    ),
)
CATALOG = CATALOG + CLASS_MODELS


def catalog_entry(name: str) -> ShippedModel:
    for entry in CATALOG:
        if entry.name == name:
            return entry
    known = ", ".join(e.name for e in CATALOG)
    raise MopError(f"no pretrained model {name!r} in the catalog; choose from {known}")
