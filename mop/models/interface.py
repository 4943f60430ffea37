"""What a learned architecture provides: the abstract base every registered model class derives from.

    class MyModel(LearnedModel):
        context_limited = False       # forward takes any T (True: at most cfg.context inputs)
        supports_stream = True        # init_cache / step_distribution / step
        supports_branch = False       # prefill / branch (the transformer's fast k-step forecasts)
        branchable_state = True       # the stream cache's `.h` (L, B, d) is the whole state (the GRU's)
        has_direct_heads = True       # forecast_heads (model.horizons > 1)
        supports_features = False     # may read input features (model.input_scale / rls_order / arx_order)
        reads_features = False        # reads them (a property of the config where supports_features)

        def __init__(self, cfg: ModelConfig) -> None:
            super().__init__(cfg)     # keeps cfg as self.cfg
        def forward(self, inputs): ...              # (B, T, d_in) -> (B, T, m); position t predicts y_{t+1}
        def predict_distribution(self, inputs): ... # (B, T, d_in) -> mean, var each (B, T, m)
        def loss(self, inputs, targets): ...        # scalar

The capabilities are declared flags, read by the predictor (mop.models.predictor) and the fast forecasts
(mop.models.rollout) to choose a path; nothing looks for methods. A flag that is True promises its methods;
the ones left False keep the defaults below, which raise MopError. A class that leaves a flag or a method
undeclared is abstract, and mop.models.registry refuses to register it (check_model_class).
"""

from __future__ import annotations

import inspect
from abc import ABC, abstractmethod
from typing import Any

from torch import Tensor, nn

from mop.config import ModelConfig
from mop.errors import MopError

# flag -> the methods a True value promises (overridden from LearnedModel's defaults)
CAPABILITIES: dict[str, tuple[str, ...]] = {
    "context_limited": (),
    "supports_stream": ("init_cache", "step_distribution"),
    "supports_branch": ("prefill", "branch"),
    "branchable_state": ("init_cache", "step_distribution"),
    "has_direct_heads": ("forecast_heads",),
    "supports_features": (),
    "reads_features": (),
}
CLASS_FLAGS = ("supports_features",)  # asked of the class, before a model is built: a bool in its body


class LearnedModel(nn.Module, ABC):
    """A learned architecture (see the module docstring). Inputs z_t = [y_t, u_t] (B, T, d_in)."""

    cfg: ModelConfig

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.cfg = cfg

    # ---- declared capabilities: each subclass sets every one (a class attribute, or a property) ----
    @property
    @abstractmethod
    def context_limited(self) -> bool:
        """True when a forward takes at most cfg.context inputs (longer trajectories are windowed)."""

    @property
    @abstractmethod
    def supports_stream(self) -> bool:
        """True when init_cache / step_distribution / step stream one input at a time, equal to forward
        while the stream is within the context (always, for a model that is not context-limited)."""

    @property
    @abstractmethod
    def supports_branch(self) -> bool:
        """True when prefill / branch continue a window's keys and values (mop.models.rollout)."""

    @property
    @abstractmethod
    def branchable_state(self) -> bool:
        """True when the stream cache's `.h` (L, B, d) is the whole state, so copies of it branch a stream."""

    @property
    @abstractmethod
    def has_direct_heads(self) -> bool:
        """True when forecast_heads reads the k-step heads of model.horizons (mop.models.horizons)."""

    @property
    @abstractmethod
    def supports_features(self) -> bool:
        """True when the architecture can read the input features of mop.models.features (a class-level
        bool: mop.train.auto asks it of the class)."""

    @property
    @abstractmethod
    def reads_features(self) -> bool:
        """True when the network reads input features computed over its whole window (running scale,
        RLS / ARX prediction: mop.models.features): fed-back inputs change them, so nothing branches."""

    # ---- required ----
    @abstractmethod
    def forward(self, inputs: Tensor) -> Tensor:
        """inputs (B, T, d_in) -> mean predictions (B, T, m); position t predicts y_{t+1}."""

    @abstractmethod
    def predict_distribution(self, inputs: Tensor) -> tuple[Tensor, Tensor]:
        """Gaussian read-out: (mean, var) each (B, T, m). MopError for readout 'mean'."""

    @abstractmethod
    def loss(self, inputs: Tensor, targets: Tensor) -> Tensor:
        """The training loss (a scalar) of predicting targets (B, T, m) from inputs (B, T, d_in)."""

    # ---- optional, promised by a flag ----
    def init_cache(self, batch_size: int) -> Any:
        """supports_stream: an empty stream state for batch_size systems."""
        raise self._lacks("supports_stream")

    def step_distribution(self, z: Tensor, cache: Any) -> tuple[Tensor, Tensor | None]:
        """supports_stream: one input z_t (B, d_in) -> (mean, var|None) of y_{t+1}, each (B, m)."""
        raise self._lacks("supports_stream")

    def step(self, z: Tensor, cache: Any) -> Tensor:
        """supports_stream: one input z_t (B, d_in) -> mean of y_{t+1} (B, m); updates cache in place."""
        return self.step_distribution(z, cache)[0]

    def forecast_heads(self, inputs: Tensor, last: bool = False, future: Tensor | None = None) -> Tensor:
        """has_direct_heads: inputs (B, T, d_in) -> (B, T, K, m), head k's mean of y_{t+k}."""
        raise self._lacks("has_direct_heads")

    def prefill(self, inputs: Tensor, last: bool = False, cache: Any = None, start: int = 0) -> Any:
        """supports_branch: forward that also returns every layer's keys and values."""
        raise self._lacks("supports_branch")

    def branch(
        self, inputs: Tensor, positions: Tensor, shared: Any, mask: Any = None, own: Any = None
    ) -> Any:
        """supports_branch: continue branches from shared keys and values."""
        raise self._lacks("supports_branch")

    def _lacks(self, flag: str) -> MopError:
        return MopError(f"model arch {self.cfg.arch!r} does not declare {flag}; it has no such path")


def check_model_class(name: str, cls: type) -> None:
    """One-line MopError unless cls derives from LearnedModel, declares every flag and required method,
    and overrides the methods each True class-level flag promises."""
    where = f"model class {cls.__name__} (arch {name!r})"
    if not (isinstance(cls, type) and issubclass(cls, LearnedModel)):
        raise MopError(f"{where} must derive from mop.models.interface.LearnedModel")
    if inspect.isabstract(cls):
        missing = ", ".join(sorted(cls.__abstractmethods__))
        raise MopError(f"{where} does not declare {missing}; see mop.models.interface.LearnedModel")
    for flag in CLASS_FLAGS:
        if not isinstance(_defined(cls, flag), bool):
            raise MopError(f"{where} must set {flag} to True or False in its class body")
    for flag, methods in CAPABILITIES.items():
        if _defined(cls, flag) is True:
            lacking = [m for m in methods if _defined(cls, m) is _defined(LearnedModel, m)]
            if lacking:
                raise MopError(f"{where} declares {flag} = True but does not define {', '.join(lacking)}")


def _defined(cls: type, name: str) -> object:
    """What the class body nearest in cls's MRO binds to `name` (None if none does)."""
    for klass in cls.__mro__:
        if name in vars(klass):
            return vars(klass)[name]
    return None
