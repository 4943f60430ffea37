"""The learned models: a registry (model.arch -> class) and the built-in architectures.

    gpt   mop.models.transformer   the paper's GPT-2-style causal transformer: the body (mop.models.gpt_body)
                                   inside the feature front end (mop.models.frontend)
    gru   mop.models.gru           GRU baseline
    deep-lru  mop.models.lru       deep linear recurrent unit (a state-space body for long free runs)

A new architecture is one module in this package with a LearnedModel subclass (mop.models.interface:
its declared capabilities and methods) decorated by @register_model("name"), imported below.
"""

from mop.models import gru, lru, transformer  # noqa: F401 (importing registers the built-in models)
from mop.models.interface import LearnedModel
from mop.models.registry import (
    build_model,
    check_arch,
    model_names,
    predictor_names,
    reads_features,
    register_model,
    skip_presets,
)

__all__ = [
    "LearnedModel",
    "build_model",
    "check_arch",
    "model_names",
    "predictor_names",
    "reads_features",
    "register_model",
    "skip_presets",
]
