"""Training the learned predictor (the paper's recipe) into a run directory, with resume and DDP.

    data.py      TrainingData, validation_batch: batches from the system family, one seeded generator
    records.py   recorded data: the split (by trajectory, in time, a --val file), normalisation, windows
    optim.py     AdamW, lr schedule, autocast, compile, train_step, validation_loss
    device.py    the device and the DDP process group
    auto.py      model.features=auto: the input feature and step budget from the family's shapes and data
    rundir.py    the run directory: config check and reuse, metrics log, checkpoint of the training state
    loop.py      train(), train_model(): the loop (signals, NaN stop, DDP slices); TrainHooks, a recipe's
                 steps around it (the fine-tune's are mop.recipe.training's)
    progress.py  the progress display

Loading a trained run (config, model, predictor) is mop.runs, which does not import the trainer.
"""

from mop.train.auto import describe_features, for_arch, resolve_features
from mop.train.data import TrainingData, validation_batch
from mop.train.device import resolve_device
from mop.train.loop import TrainHooks, TrainState, train, train_model
from mop.train.optim import LossModule, autocast, learning_rate, make_optimizer, maybe_compile, train_step
from mop.train.rundir import resolve_config

__all__ = [
    "LossModule",
    "TrainHooks",
    "TrainState",
    "TrainingData",
    "autocast",
    "describe_features",
    "for_arch",
    "learning_rate",
    "make_optimizer",
    "maybe_compile",
    "resolve_config",
    "resolve_device",
    "resolve_features",
    "train",
    "train_model",
    "train_step",
    "validation_batch",
]
