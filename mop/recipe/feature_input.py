"""The records a run of data.feature_input = "free-run" trains on: its feature fitted, its run added.

Before training, the records recipe's least-squares feature (mop.recipe.records.feature_orders: the ARX
`mop fit arx` chooses on the training part, its cubic NARX or longer ARX where those simulate that part's
end better) is fitted on the training part, as the held-out check fits it (mop.recipe.selection); a cubic
NARX is read only where it also scores below the linear feature (the ARX or longer ARX feature_orders
gives without cubes) on the check's own stretches (the held-out data and the long run), by which the check
later weighs every candidate. On the real cascaded tanks the cubic NARX chosen on the training part's end
scored 0.866 there against 0.582 for the ARX(3, 10); the network reading the ARX's run simulated the test
at 0.3827 / 0.4307 / 0.3807 V (seeds 0-2) against 0.3673 / 0.4838 / 0.3873 reading the cubic's. Every
record the network trains and validates on gets that feature's run as m more inputs, its outputs less that
run (mop.models.feature_input.record_with_channel), from its first n measured outputs (the
held-out check's window, mop.recipe.selection.init_window). The run holds the feature (RUN/feature), and
mop.runs.load_predictor reads the records' own channels through it.
"""

from __future__ import annotations

from pathlib import Path

from mop.atomic import write_json
from mop.config import RunConfig
from mop.errors import MopError
from mop.identify.narx_model import FittedNARX
from mop.identify.store import FILE as FITTED_FILE
from mop.models.feature_input import FEATURE_DIR, INIT_KEY, record_with_channel
from mop.recipe.records import fitted_features, recipe_reads
from mop.recipe.selection import check_scores, init_window
from mop.train.records import RecordedData, TrainingRecords


def reads_feature_run(config: RunConfig) -> bool:
    """Whether the run's network reads its feature's run (data.feature_input = "free-run")."""
    return config.data is not None and config.data.reads_feature_run


def run_feature(record: RecordedData) -> FittedNARX:
    """The records recipe's feature fitted on the record's training part (in its normalisation), with the
    window each trained record's run starts from (info[INIT_KEY]); one-line MopError where the record has
    no inputs or missing outputs."""
    if not recipe_reads(record):
        raise MopError(
            f"data.feature_input=free-run fits a least-squares model on {record.path}, which needs inputs "
            "and complete outputs; fill the gaps, or set data.feature_input=none"
        )
    feature, linear = fitted_features(record)  # linear: without the cubed lags feature has (or None)
    if linear is not None and check_scores(linear, record)["score"] < check_scores(feature, record)["score"]:
        feature = linear
    feature.info[INIT_KEY] = init_window(record)
    return feature


def with_feature_run(records: TrainingRecords, feature: FittedNARX) -> TrainingRecords:
    """The records (and validation records) as the network trains on them: each with the feature's run from
    its first info[INIT_KEY] outputs as inputs, its outputs less that run."""
    n = int(feature.info[INIT_KEY])
    shown = lambda rs: tuple(record_with_channel(feature, r, n) for r in rs)  # noqa: E731
    validation = None if records.validation is None else shown(records.validation)
    return TrainingRecords(shown(records.records), validation, records.source, records.validation_source)


def save_feature(run_dir: Path, feature: FittedNARX) -> None:
    """RUN/feature/fitted.json, which the run's predictor reads (mop.runs.load_predictor)."""
    (run_dir / FEATURE_DIR).mkdir(parents=True, exist_ok=True)
    write_json(run_dir / FEATURE_DIR / FITTED_FILE, {"format": 1, **feature.to_json()})
