"""Presets: model size, optimisation and test-set size, applied under every experiment's own settings."""

from __future__ import annotations

import dataclasses

import torch

from mop.config import ModelConfig, RunConfig, TrainConfig
from mop.errors import MopError


@dataclasses.dataclass(frozen=True)
class Preset:
    """Model size, optimisation and test-set size of one preset. What a predictor does under a preset
    (its options, whether it is trained) is the predictor's own metadata (preset_options, skip_presets).
    """

    model: ModelConfig
    train: TrainConfig
    num_test_systems: int


PRESETS: dict[str, Preset] = {
    # the paper: GPT-2 12 layers / 8 heads / 256 wide, M = 20000, T = 50, 10000 steps of batch 64, N = 1000
    "paper": Preset(
        ModelConfig(num_layers=12, num_heads=8, width=256),
        TrainConfig(steps=10000, batch_size=64, num_source_systems=20000, horizon=50),
        num_test_systems=1000,
    ),
    # laptop CPU (2 cores): fresh systems every batch, a 2 x 64 model, lr 3e-3 with warm-up and cosine decay.
    # `mop bench recipe`: as good as the former 4 x 128 preset (linear MOP/KF ratio over t in [20,50]
    # 1.029 [1.025, 1.032]) at ~1/5 of its FLOPs. The GRU baseline is off (--with gru turns it on).
    # model.features=auto (mop.train.auto): the online identifier feature (ARX / RLS-AR, its orders, the
    # running scale) from the family's shapes and data, and the 2500 steps scaled by its step cost (2100
    # with the identifier), for every family; an experiment or a user that names a feature key sets it.
    "small": Preset(
        ModelConfig(num_layers=2, num_heads=4, width=64, features="auto"),
        TrainConfig(
            steps=2500,
            batch_size=64,
            lr=3e-3,
            lr_schedule="cosine",
            warmup_steps=125,
            num_source_systems=0,
            horizon=50,
            compile="off",
            checkpoint_every=500,
        ),
        num_test_systems=500,
    ),
    # tests and CI: < 60 s on 2 cores
    "smoke": Preset(
        ModelConfig(num_layers=1, num_heads=2, width=32),
        TrainConfig(
            steps=30,
            batch_size=16,
            lr=1e-3,
            num_source_systems=0,
            horizon=50,
            compile="off",
            log_every=10,
            checkpoint_every=30,
        ),
        num_test_systems=32,
    ),
}


def get_preset(name: str) -> Preset:
    if name not in PRESETS:
        raise MopError(f"unknown preset {name!r}; choose one of {', '.join(PRESETS)}")
    return PRESETS[name]


def default_preset() -> str:
    """The preset `mop reproduce` and `mop train` use unless told: "paper" where a CUDA GPU is present,
    else "small" (the CPU preset)."""
    return "paper" if torch.cuda.is_available() else "small"


def preset_config(name: str) -> RunConfig:
    """The RunConfig of preset `name` on its own (the default family, the preset's model and training)."""
    p = get_preset(name)
    return RunConfig(model=p.model, train=p.train)
