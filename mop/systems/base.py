"""What every system family shares: configs, the family registry, sampling helpers and the redraw loop; and,
re-exported from their own modules, Trajectories (mop.systems.trajectories) and the state-space description
filters consume (mop.systems.state_space).

Time indexing used everywhere in mop: a trajectory of horizon T holds outputs y_0..y_T
(T + 1 of them). Inputs u_t (where a family has them) act between y_t and y_{t+1}:
x_{t+1} = f(x_t, u_t) + w_t, y_t = C x_t + v_t.

A new family is one module:

    @dataclass(frozen=True)
    class PendulumConfig(SystemConfig):        # only its own knobs, validated in __post_init__
        family: str = "pendulum"
        damping: float = 0.1

    @dataclass(frozen=True)
    class PendulumParams(SystemParams):        # what its systems are made of, each field (B, ...)
        length: Tensor                         # (B,)
        C: Tensor                              # (B, m, n)

    @register_family("pendulum", PendulumConfig)
    class Pendulum(SystemFamily):
        Params = PendulumParams                                   # the type Trajectories.params has
        def sample(self, num_systems, *, generator): ...          # PendulumParams of B systems
        def simulate(self, params, horizon, *, generator): ...    # Trajectories
        @staticmethod
        def state_space(params): ...                              # StateSpace for the EKF / UKF / PF
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

import torch
from torch import Tensor

from mop.errors import MopError, check
from mop.registry import Registry
from mop.systems.params import SystemParams, require_params  # noqa: F401 (re-exported)
from mop.systems.state_space import (  # noqa: F401 (re-exported: the families' API)
    LINEAR_MODEL_ARRAYS,
    LinearModelParams,
    Projection,
    StateSpace,
    Transition,
    TransitionJacobian,
    linear_model_from_params,
    linear_state_space,
)
from mop.systems.trajectories import Trajectories

MAX_REDRAWS = 100


@dataclass(frozen=True)
class SystemConfig:
    """A family's settings. Each family subclasses this with its own knobs and its name as the default of
    `family`; constructing the base class builds the registered family's config: SystemConfig(family=
    "quadrotor") is a QuadrotorConfig, and SystemConfig() is the config of the family registered with
    default=True (FAMILIES.default(): the paper's linear systems).

    max_abs: trajectories with any |x| or |y| above it are redrawn (DESIGN.md: 50).
    """

    family: str = ""  # every family's config sets its own name here
    max_abs: float = 50.0

    def __new__(cls, *args: Any, **kwargs: Any) -> SystemConfig:
        return object.__new__(cls.resolve_class(kwargs))

    @classmethod
    def resolve_class(cls, data: dict[str, Any]) -> type:
        """The dataclass that `data` (a dict with "family", or none: the default family) builds: used by
        mop.config.from_dict."""
        if cls is not SystemConfig:
            return cls
        return config_class(data["family"] if "family" in data else FAMILIES.default())

    def __post_init__(self) -> None:
        expected = config_class(self.family)
        check(
            isinstance(self, expected),
            f"system family {self.family!r} takes a {expected.__name__}, not a {type(self).__name__}",
        )
        check(self.max_abs > 0, f"system.max_abs must be > 0, got {self.max_abs}")


class SystemFamily:
    """A distribution over dynamical systems (D_sys in the paper), batched and seeded.

    One call samples or simulates B systems at once, on any device, and all randomness comes from the
    torch.Generator passed in (same seed -> same numbers). Subclasses set state_dim, output_dim, input_dim
    in __init__ and implement sample, simulate and (for predictors that know the system) state_space.
    """

    name: ClassVar[str] = ""
    Config: ClassVar[type[SystemConfig]] = SystemConfig
    Params: ClassVar[type[SystemParams]] = SystemParams  # each family declares its own (register_family)
    # False where state_space only approximates the simulated systems (colored-noise: the paper's white-noise
    # Kalman filter), so no predictor may treat its filter as the optimum (mop.filters.linear_gaussian)
    exact_state_space: ClassVar[bool] = True
    state_dim: int
    output_dim: int
    input_dim: int = 0

    def __init__(self, config: SystemConfig, dtype: torch.dtype = torch.float32) -> None:
        self.config, self.dtype = config, dtype

    def sample(self, num_systems: int, *, generator: torch.Generator) -> SystemParams:
        """Parameters of `num_systems` systems, each field with leading dim B."""
        raise NotImplementedError

    def simulate(self, params: SystemParams, horizon: int, *, generator: torch.Generator) -> Trajectories:
        """One trajectory of `horizon` steps (horizon + 1 outputs) per system; its params are of type Params
        (a family may add fields only a simulation gives, e.g. the normalization of lti-siso)."""
        raise NotImplementedError

    @staticmethod
    def state_space(params: SystemParams) -> StateSpace:
        """The systems in `params` as a StateSpace; families without one refuse system-aware predictors."""
        raise MopError("this family gives no state-space model; use predictors that need no system knowledge")

    def generate(self, num_systems: int, horizon: int, *, generator: torch.Generator) -> Trajectories:
        """sample + simulate, then redraw (sample and simulate again) only the systems that left +-max_abs."""
        if num_systems < 1 or horizon < 1:
            raise MopError(
                f"need at least 1 system and horizon >= 1, got {num_systems} systems, horizon {horizon}"
            )
        traj = self.simulate(self.sample(num_systems, generator=generator), horizon, generator=generator)
        for _ in range(MAX_REDRAWS):
            bad = out_of_bounds(traj, self.config.max_abs)
            if not bad.any():
                return cast(traj, self.dtype)
            idx = bad.nonzero().squeeze(1)
            new = self.simulate(self.sample(len(idx), generator=generator), horizon, generator=generator)
            traj = replace_rows(traj, idx, new)
        raise MopError(
            f"{int(bad.sum())} systems stayed outside |x|,|y| <= {self.config.max_abs} after "
            f"{MAX_REDRAWS} redraws; raise system.max_abs or lower the noise / spectral_radius"
        )


# filled by the family modules, which mop.systems imports; plugins through the entry points of mop.families
FAMILIES: Registry = Registry("system family", group="mop.families")


def register_family(name: str, config: type[SystemConfig], default: bool = False) -> Callable[[type], type]:
    """Class decorator: register a SystemFamily subclass under `name` with its config dataclass. The class
    declares its parameter type as `Params` (a SystemParams dataclass); one that does not (a family written
    with dict params) is refused in one line.

    default: the family a config without a family is (SystemConfig(), a RunConfig's default system); one
    family is (mop.systems.linear).
    """

    def decorate(cls: type) -> type:
        declared = getattr(cls, "Params", SystemParams)
        if (
            not (isinstance(declared, type) and issubclass(declared, SystemParams))
            or declared is SystemParams
        ):
            raise MopError(
                f"family {name!r} declares no parameter type: set `Params` on {cls.__name__} to a frozen "
                "dataclass of SystemParams (dict params are not read; see examples/pendulum.py)"
            )
        cls.name, cls.Config = name, config
        FAMILIES.add(name, cls, default=default)
        return cls

    return decorate


def config_class(family: str) -> type[SystemConfig]:
    return FAMILIES.get(family).Config


def state_space_of(traj: Trajectories) -> StateSpace:
    """The StateSpace of the systems in `traj` from its family; for data without a family but with the
    fields A, C, Q, R (a known linear model, LinearModelParams), that model; else MopError."""
    if traj.family:
        return FAMILIES.get(traj.family).state_space(traj.params)
    if traj.params is None:
        raise MopError(
            "these trajectories carry no system family, so a predictor that knows the system cannot run; "
            "use one that needs no model (`mop predict --help` lists them)"
        )
    model = LinearModelParams.from_arrays(traj.params.as_dict(), by="a known linear model", where="the data")
    return linear_model_from_params(model)


# ----------------------------------------------------------------------------- sampling helpers


def uniform(
    shape: tuple[int, ...],
    low: float,
    high: float,
    generator: torch.Generator,
    dtype: torch.dtype = torch.float64,
) -> Tensor:
    """U[low, high] draws on the generator's device."""
    draw = torch.rand(shape, generator=generator, device=generator.device, dtype=dtype)
    return low + (high - low) * draw


def normal(shape: tuple[int, ...], generator: torch.Generator, dtype: torch.dtype = torch.float64) -> Tensor:
    """N(0, 1) draws on the generator's device (float32 draws are ~4x faster on CPU)."""
    return torch.randn(shape, generator=generator, device=generator.device, dtype=dtype)


def scaled_eye(num_systems: int, dim: int, var: float, device: torch.device) -> Tensor:
    """(B, d, d) var * I in float64."""
    return (var * torch.eye(dim, dtype=torch.float64, device=device)).expand(num_systems, dim, dim).clone()


def out_of_bounds(traj: Trajectories, max_abs: float) -> Tensor:
    """(B,) bool: any |x| or |y| above max_abs (or not finite)."""
    big = lambda t: ~(t.abs() <= max_abs).flatten(1).all(1)  # noqa: E731
    bad = big(traj.y)
    return bad if traj.x is None else bad | big(traj.x)


def replace_rows(traj: Trajectories, idx: Tensor, new: Trajectories) -> Trajectories:
    """traj with systems idx replaced by the systems of `new` (same family and horizon)."""

    def put(old: Tensor | None, fresh: Tensor | None) -> Tensor | None:
        if old is None:
            return None
        old = old.clone()
        old[idx] = fresh
        return old

    params = traj.params
    if params is not None:
        fresh = new.params.as_dict()
        params = type(params)(**{k: put(v, fresh[k]) for k, v in params.as_dict().items()})
    return Trajectories(put(traj.y, new.y), put(traj.u, new.u), put(traj.x, new.x), params, traj.family)


def cast(traj: Trajectories, dtype: torch.dtype) -> Trajectories:
    """Floating tensors to dtype (integer params such as switch_time stay as they are)."""
    return traj._map(lambda t: t.to(dtype) if t.is_floating_point() else t)
