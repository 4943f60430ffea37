"""The learned model's network section, one config class per architecture, found by model.arch's name.

The network's keys (model.num_layers, model.width, ...) are model.* keys: ModelConfig holds them flat, so
every override, experiment file, saved config.json and its identity stay as they were, and
ModelConfig.network gives those its architecture reads as that architecture's section, whose
__post_init__ checks them. Meanings and defaults are ModelConfig's (mop.config).

    @register_network_config("gpt")
    @dataclasses.dataclass(frozen=True)
    class GptConfig(NetworkConfig):
        num_heads: int
        ...

An architecture that registers no section (a plug-in's) gets GenericNetworkConfig: every network key, with
every check. This module is in the config layer and imports no model code; a plug-in architecture registers
its section here beside its model class (mop.models.registry).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, TypeVar

from mop.errors import MopError, check, check_choice, check_int

# the network's keys, in the order ModelConfig declares them (model.arch names the section)
NETWORK_KEYS: tuple[str, ...] = (
    "num_layers",
    "num_heads",
    "width",
    "context",
    "input_dim",
    "output_dim",
    "readout",
    "dropout",
    "position",
)

NETWORK_CHOICES: dict[str, tuple[str, ...]] = {
    "readout": ("mean", "gaussian"),
    "position": ("learned", "rope"),
}


@dataclasses.dataclass(frozen=True)
class NetworkConfig:
    """The network keys every architecture reads (model.* keys; see the module docstring)."""

    num_layers: int
    width: int
    context: int
    input_dim: int
    output_dim: int
    readout: str
    dropout: float

    def __post_init__(self) -> None:
        self._check_sizes()
        check(self.input_dim >= 0 and self.output_dim >= 0, "model.input_dim/output_dim must be >= 0")
        check(0 <= self.dropout < 1, f"model.dropout must be in [0, 1), got {self.dropout}")
        for name, choices in NETWORK_CHOICES.items():
            if name in self.keys():
                check_choice(f"model.{name}", getattr(self, name), choices)

    def _check_sizes(self) -> None:
        """The integer sizes (each >= 1), and how they must fit together."""
        for name in ("num_layers", "num_heads", "width", "context"):
            if name in self.keys():
                check_int(f"model.{name}", getattr(self, name), 1)

    @classmethod
    def keys(cls) -> tuple[str, ...]:
        """The model.* keys this section holds, in ModelConfig's order."""
        own = {f.name for f in dataclasses.fields(cls)}
        return tuple(key for key in NETWORK_KEYS if key in own)

    @classmethod
    def of(cls, model: Any) -> NetworkConfig:
        """This section of `model`, a ModelConfig (or anything with the network's keys as attributes)."""
        return cls(**{key: getattr(model, key) for key in cls.keys()})


@dataclasses.dataclass(frozen=True)
class GenericNetworkConfig(NetworkConfig):
    """Every network key, with every check: the section of an architecture that registers none."""

    num_heads: int
    position: str

    def _check_sizes(self) -> None:
        super()._check_sizes()
        check(
            self.width % self.num_heads == 0,
            f"model.num_heads ({self.num_heads}) must divide model.width ({self.width})",
        )


S = TypeVar("S", bound=type[NetworkConfig])

_SECTIONS: dict[str, type[NetworkConfig]] = {}


def register_network_config(name: str) -> Callable[[S], S]:
    """Class decorator: model.arch == name reads its network keys as this section. Names are unique."""

    def register(cls: S) -> S:
        if name in _SECTIONS:
            taken = _SECTIONS[name].__name__
            raise MopError(f"network config of {name!r} is already registered (by {taken})")
        if not (isinstance(cls, type) and issubclass(cls, NetworkConfig)):
            raise MopError(f"network config of {name!r} must derive from NetworkConfig, got {cls!r}")
        _SECTIONS[name] = cls
        return cls

    return register


def network_config_class(arch: str) -> type[NetworkConfig]:
    """The section registered under `arch`; GenericNetworkConfig for an architecture without one."""
    return _SECTIONS.get(arch, GenericNetworkConfig)


def network_config_names() -> list[str]:
    """The architectures with a section of their own, sorted."""
    return sorted(_SECTIONS)


@register_network_config("gpt")
@dataclasses.dataclass(frozen=True)
class GptConfig(GenericNetworkConfig):
    """The GPT-2 body (mop.models.transformer): every network key; num_heads must divide width, position
    is "learned" or "rope"."""


@register_network_config("gru")
@dataclasses.dataclass(frozen=True)
class GruConfig(NetworkConfig):
    """The GRU baseline (mop.models.gru): it has no attention heads and no position embedding, so it reads
    neither model.num_heads nor model.position (left unchecked)."""


@register_network_config("deep-lru")
@dataclasses.dataclass(frozen=True)
class LruConfig(NetworkConfig):
    """The deep linear recurrent unit (mop.models.lru): no attention heads, no position embedding and no
    context limit, so it reads neither model.num_heads nor model.position (left unchecked); model.width is
    its layers' width and their complex modes each."""
