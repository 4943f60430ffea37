"""The records a run trains on, as given: read once at the edge (read_given), named in the config as
provenance (with_records), completed by a config's own data (run_records, named_records) and split as
config.data asks (split). Both the from-scratch and the fine-tune configs start here; nothing below reads
the record's file again.
"""

from __future__ import annotations

import dataclasses

from mop.config import DataConfig, RunConfig
from mop.errors import MopError
from mop.record import read_records
from mop.train.records import RecordedData, TrainingRecords


def read_given(data: str | TrainingRecords | None, val: str | None) -> TrainingRecords | None:
    """The records of `mop train --data FILE [--val FILE]`, read once here (the edge), or those given in
    memory; None without --data. One-line MopError for --val without --data."""
    if data is None:
        if val is not None:
            raise MopError("--val FILE is the validation record of --data FILE: give --data too")
        return None
    if isinstance(data, TrainingRecords):
        return data
    return TrainingRecords.read(data, val)


def with_records(config: RunConfig, records: TrainingRecords | None) -> RunConfig:
    """Layer 2: --data and --val, as data.path and data.validation_path (where the records came from: their
    provenance); the normalisation is left to the trainer (a saved config's is refitted)."""
    if records is None:
        return config
    unfitted = dict.fromkeys(("y_mean", "y_std", "u_mean", "u_std"))
    base = config.data or DataConfig(path=records.source)
    val = records.validation_source if records.validation is not None else base.validation_path
    return dataclasses.replace(
        config, data=dataclasses.replace(base, path=records.source, validation_path=val, **unfitted)
    )


def run_records(records: TrainingRecords | None, base: RunConfig) -> TrainingRecords | None:
    """The records the run trains on: those given (--data, --val), else those of the base config's own
    data (a RunConfig file or an --init source naming data.path), read here once; --data without --val on a
    config naming its validation file (data.validation_path) validates on that file, as the config says."""
    if base.data is None:
        return records
    if records is None:
        return TrainingRecords.read(base.data.path, base.data.validation_path or None)
    if records.validation is not None or not base.data.validation_path:
        return records
    path = base.data.validation_path
    return TrainingRecords(records.records, tuple(read_records(path)), records.source, path)


def named_records(records: TrainingRecords | None, config: RunConfig) -> TrainingRecords | None:
    """run_records after the overrides, which may name the data (data.path, data.validation_path); a
    data.path override beside --data is refused in one line (the record is named once)."""
    if records is not None and config.data is not None and config.data.path != records.source:
        raise MopError(f"data.path={config.data.path} beside --data {records.source}: name the record once")
    return run_records(records, config)


def split(config: RunConfig, records: TrainingRecords | None) -> RecordedData | None:
    """The records split as config.data asks (None without data): the record a recipe's step looks at."""
    return None if config.data is None else records.split(config.data)
