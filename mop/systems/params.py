"""Typed system parameters: each family declares what its systems are made of as a frozen dataclass of
tensors (as dynamax's ParamsLGSSM), and predictors that know the system read its fields (params.A).

    @dataclass(frozen=True)
    class PendulumParams(SystemParams):
        \"\"\"length, damping, gain (B,); C (B, 2, 2); Q, R, P0 (B, 2, 2); x0_mean (B, 2).\"\"\"
        length: Tensor
        ...

Every field is a tensor with leading dimension B (one row per system), or None where the type gives it that
default (an optional parameter, e.g. the input matrix of a known linear model without inputs). Saved data
holds field F as the array param_F (Trajectories.to_numpy_dict); from_arrays reads it back.

One check names a missing parameter for every consumer: require_params(params, fields, by=predictor) raises a
one-line MopError naming the predictor, the fields it needs and that the data lacks them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Collection, Iterable, Mapping
from typing import Any, TypeVar

import numpy as np
import torch
from torch import Tensor

from mop.errors import MopError

P = TypeVar("P", bound="SystemParams")


@dataclasses.dataclass(frozen=True)
class SystemParams:
    """The base of every family's parameter type (it has no fields itself)."""

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if value is not None and not isinstance(value, (Tensor, np.ndarray)):
                raise MopError(
                    f"{type(self).__name__}.{f.name} must be a tensor with leading dim B, got "
                    f"{type(value).__name__}"
                )

    @classmethod
    def names(cls) -> tuple[str, ...]:
        """Every field, in declaration order."""
        return tuple(f.name for f in dataclasses.fields(cls))

    @classmethod
    def required(cls) -> tuple[str, ...]:
        """The fields without a default: what saved data must hold for this type."""
        missing = dataclasses.MISSING
        return tuple(f.name for f in dataclasses.fields(cls) if f.default is missing)

    @classmethod
    def extend(cls: type[P], base: SystemParams, **fields: Any) -> P:
        """A `cls` from the fields of `base` that cls declares plus `fields` (which win): e.g. a sampled
        system and what a simulation adds (lti-siso's normalization), or a parent type and the new fields."""
        kept = {k: v for k, v in base.as_dict().items() if k in cls.names()}
        return cls(**(kept | fields))

    def present(self) -> tuple[str, ...]:
        """The fields that hold a tensor (not None)."""
        return tuple(n for n, v in self.as_dict().items() if v is not None)

    def as_dict(self) -> dict[str, Any]:
        """{field: value} (shallow: the tensors themselves, not copies)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    def map(self: P, fn: Callable[[Any], Any]) -> P:
        """The same type with fn applied to every field that is not None (e.g. Tensor.double, a row index)."""
        return type(self)(**{k: None if v is None else fn(v) for k, v in self.as_dict().items()})

    def select(self: P, index: Any) -> P:
        """The systems picked by `index` along the leading (batch) dimension."""
        return self.map(lambda t: t[index])

    def to_arrays(self) -> dict[str, np.ndarray]:
        """{field: numpy array} of the fields that hold a tensor (as np.savez stores them)."""
        return {k: v.cpu().numpy() for k, v in self.as_dict().items() if v is not None}

    @classmethod
    def from_arrays(cls: type[P], arrays: Mapping[str, Any], *, by: str, where: str) -> P:
        """The parameters in `arrays` ({field: array or tensor}, e.g. a file's param_<field> arrays); fields
        of other types are ignored; a missing required field is a MopError (require_params)."""
        given = {k: v for k, v in arrays.items() if v is not None and k in cls.names()}
        require_params(given.keys(), cls.required(), by=by, where=where)
        return cls(**{k: torch.as_tensor(v) for k, v in given.items()})


def lacking(params: SystemParams | Collection[str] | None, needed: Iterable[str]) -> list[str]:
    """The fields of `needed` that `params` does not hold: a parameter object (a field set to None is not
    held), the names a file holds, or None (no parameters at all)."""
    if params is None:
        have: Collection[str] = ()
    elif isinstance(params, SystemParams):
        have = params.present()
    else:
        have = params
    return [name for name in needed if name not in have]


def require_params(
    params: SystemParams | Collection[str] | None,
    needed: Iterable[str],
    *,
    by: str,
    where: str = "these trajectories",
) -> None:
    """The one check of system parameters, for every predictor, analysis and loader: MopError (one line)
    naming `by` (who needs them), the fields of `needed` that `params` lacks (see lacking) and `where`."""
    missing = lacking(params, needed)
    if not missing:
        return
    if params is None:
        carry = "they carry no system parameters"
    elif isinstance(params, SystemParams):
        carry = f"they carry {type(params).__name__}: {', '.join(params.present())}"
    else:
        carry = f"it has {', '.join(sorted(params)) or 'none'}"
    s = "s" if len(missing) > 1 else ""
    raise MopError(
        f"{by} needs the system parameter{s} {', '.join(missing)}, missing from {where} ({carry}); "
        "use it on data whose system has them, or a predictor that needs no system"
    )
