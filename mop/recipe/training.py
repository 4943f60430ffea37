"""Training a config of mop.recipe: mop.train's loop with the fine-tune's steps around it.

RECIPE_HOOKS hands the loop (mop.train.TrainHooks), each step doing nothing where its key is off:
    check            train.init's architecture (mop.recipe.source.check_init) and whether
                     train.shrink_correction can apply (mop.recipe.shrink.check_shrink), before any work;
    initial_weights  train.init's weights at step 0 (mop.recipe.source.load_init);
    after            train.shrink_correction's gain, chosen and written after the last step
                     (mop.recipe.shrink.apply_chosen_gain).
A config without those keys trains exactly as mop.train.train trains it.
"""

from __future__ import annotations

import dataclasses
import functools
import os
from collections.abc import Callable
from pathlib import Path

from torch import nn

from mop.config import RunConfig
from mop.recipe.shrink import apply_chosen_gain, check_shrink
from mop.recipe.source import check_init, load_init
from mop.train import TrainHooks
from mop.train import train as train_loop
from mop.train.records import TrainingRecords


def check(config: RunConfig) -> None:
    """The recipe's refusals, in one line each, before the run directory is touched."""
    check_init(config)
    check_shrink(config)


def initial_weights(config: RunConfig, model: nn.Module) -> None:
    """A fine-tune's step 0: the source's weights (train.init); other runs keep their seeded start."""
    if config.train.init:
        load_init(config, model)


RECIPE_HOOKS = TrainHooks(check=check, initial_weights=initial_weights, after=apply_chosen_gain)


def train(
    config: RunConfig,
    out_dir: str | os.PathLike,
    *,
    progress: bool = True,
    wait: bool = True,
    fresh: bool = False,
    announce: Callable[[str], None] | None = None,
    records: TrainingRecords | None = None,
    deadline: float | None = None,
) -> Path:
    """mop.train.train with RECIPE_HOOKS: train (or resume, or reuse) the run `out_dir` of `config`, on
    config.data's `records` in memory where given (None: read from data.path), stopping unfinished at
    `deadline` (a time of mop.train.loop.clock) where one is given."""
    hooks = RECIPE_HOOKS
    if records is not None:
        hooks = dataclasses.replace(hooks, after=functools.partial(apply_chosen_gain, records=records))
    return train_loop(
        config,
        out_dir,
        progress=progress,
        wait=wait,
        fresh=fresh,
        announce=announce,
        hooks=hooks,
        records=records,
        deadline=deadline,
    )
