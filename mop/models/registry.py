"""The model registry: each learned architecture registers its class under the name model.arch selects.

    @register_model("gpt", predictor="mop")
    class Transformer(LearnedModel):
        def __init__(self, cfg: ModelConfig) -> None: ...

A model class derives from mop.models.interface.LearnedModel, declares its capability flags and defines
the methods they promise (see there); register_model refuses one that does not, in one line. Importing its
module registers it.
"""

from __future__ import annotations

from collections.abc import Callable

from mop.config import ModelConfig
from mop.errors import MopError
from mop.models.interface import LearnedModel, check_model_class

_MODELS: dict[str, type[LearnedModel]] = {}
_PREDICTORS: dict[str, str] = {}  # arch -> the name of its learned predictor
_SKIP_PRESETS: dict[str, tuple[str, ...]] = {}  # arch -> presets under which it is trained only if asked


def register_model(
    name: str, predictor: str = "", skip_presets: tuple[str, ...] = ()
) -> Callable[[type[LearnedModel]], type[LearnedModel]]:
    """Class decorator: build_model(cfg) with cfg.arch == name builds this class. Names are unique, and the
    class must be a complete LearnedModel (mop.models.interface.check_model_class).

    predictor: the name its trained runs go by as a predictor (mop.runs registers it; default: `name`).
    skip_presets: presets under which experiments leave it out unless asked (`mop reproduce --with NAME`).
    """

    def register(cls: type[LearnedModel]) -> type[LearnedModel]:
        if name in _MODELS:
            raise MopError(f"model architecture {name!r} is already registered (by {_MODELS[name].__name__})")
        check_model_class(name, cls)
        _MODELS[name], _PREDICTORS[name], _SKIP_PRESETS[name] = cls, predictor or name, tuple(skip_presets)
        return cls

    return register


def predictor_names() -> dict[str, str]:
    """arch -> the predictor name of its trained runs, for every registered architecture."""
    return dict(_PREDICTORS)


def skip_presets(arch: str) -> tuple[str, ...]:
    """The presets under which architecture `arch` is trained only when asked."""
    return _SKIP_PRESETS.get(arch, ())


def reads_features(arch: str) -> bool:
    """Whether architecture `arch` can read the input features (model.input_scale, rls_order, arx_order):
    its class's declared supports_features (mop.models.interface)."""
    check_arch(arch)
    return _MODELS[arch].supports_features


def model_names() -> list[str]:
    """The registered architectures, sorted."""
    return sorted(_MODELS)


def check_arch(arch: str) -> None:
    """MopError naming the known architectures when `arch` is not registered."""
    if arch not in _MODELS:
        known = ", ".join(repr(name) for name in model_names())
        raise MopError(f"model.arch must be one of {known}, got {arch!r}")


def build_model(cfg: ModelConfig) -> LearnedModel:
    """The model registered under cfg.arch (the paper's transformer is 'gpt')."""
    check_arch(cfg.arch)
    return _MODELS[cfg.arch](cfg)
