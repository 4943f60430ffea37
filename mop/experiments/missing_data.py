"""`missing-data` (beyond the paper): outputs missing at random (a fraction p per channel and step) and in
whole-step bursts. MOP trained with random drop-outs (and its observation mask) against the Kalman filter that
conditions on exactly what was measured (the optimum) and RLS filling its regressors with its own predictions;
errors are measured on the measured outputs only.
"""

from __future__ import annotations

from mop.experiments.spec import Claim, Condition, Experiment, Measure

MISSING_FRACTIONS = (0.0, 0.1, 0.3, 0.5)
BURSTS = {"burst_rate": 0.05, "burst_length": 5}  # a 5-step gap starts at 5% of the steps (~23% missing)
TRAIN_DROP_OUTS = {
    "system.family": "linear",
    "train.missing_rate": 0.3,
    "train.missing_burst_rate": 0.02,
    "train.missing_burst_length": 5,
}


def _condition(p: float) -> Condition:
    return Condition(f"p={p:.2f}", missing={"rate": p} if p else {}, x=("missing fraction p", p))


MISSING_DATA = Experiment(
    name="missing-data",
    title="missing outputs (beyond the paper)",
    description="linear systems with a fraction p of the outputs missing at random and with 5-step bursts; "
    "MOP is trained once with drop-outs (30% per channel and step, 2% burst starts) and reads a mask of what "
    "was measured; the KF conditions on the measured channels only; errors over the measured outputs",
    train=TRAIN_DROP_OUTS,
    predictors=("mop", "kalman", "rls", "last"),
    conditions=(
        *(_condition(p) for p in MISSING_FRACTIONS),
        Condition("bursts", missing=dict(BURSTS)),
    ),
    figures=("ratio_by_x", "error"),
    claims=(
        Claim(
            "at p = 0.3 MOP is within 10% of the KF that conditions on what was measured (t in [20, T])",
            Measure("mse_ratio", condition="p=0.30"),
            "<=",
            1.1,
        ),
        Claim(
            "MOP/KF at its worst over every p and the bursts (reported)",
            Measure("mse_ratio", condition="*", reduce="max"),
        ),
        Claim("with 5-step bursts, MOP against the KF (reported)", Measure("mse_ratio", condition="bursts")),
        Claim(
            "at p = 0.3 MOP's error is below RLS's",
            Measure("mean_error", condition="p=0.30"),
            "<",
            Measure("mean_error", predictor="rls", condition="p=0.30"),
        ),
        Claim(
            "with bursts MOP's error is below RLS's",
            Measure("mean_error", condition="bursts"),
            "<",
            Measure("mean_error", predictor="rls", condition="bursts"),
        ),
    ),
)
