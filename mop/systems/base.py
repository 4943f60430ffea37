"""What every system family shares: trajectories, configs, the state-space description filters consume,
the family registry, sampling helpers and the redraw loop.

Time indexing used everywhere in mop: a trajectory of horizon T holds outputs y_0..y_T
(T + 1 of them). Inputs u_t (where a family has them) act between y_t and y_{t+1}:
x_{t+1} = f(x_t, u_t) + w_t, y_t = C x_t + v_t.

A new family is one module:

    @dataclass(frozen=True)
    class PendulumConfig(SystemConfig):        # only its own knobs, validated in __post_init__
        family: str = "pendulum"
        damping: float = 0.1

    @register_family("pendulum", PendulumConfig)
    class Pendulum(SystemFamily):
        def sample(self, num_systems, *, generator): ...          # params, each (B, ...)
        def simulate(self, params, horizon, *, generator): ...    # Trajectories
        @staticmethod
        def state_space(params): ...                              # StateSpace for the EKF / UKF / PF
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
import torch
from torch import Tensor

from mop.errors import MopError, check
from mop.registry import Registry

MAX_REDRAWS = 100


@dataclass
class Trajectories:
    """A batch of simulated (or measured) trajectories.

    y: (B, T+1, m) outputs y_0..y_T; NaN marks an output channel not measured at a step (a gap; `observed`
        is the mask). Every predictor skips what was not measured; inputs u must be complete.
    u: (B, T+1, k) inputs u_0..u_T, or None for families without inputs.
    x: (B, T+1, n) true states, or None for measured data.
    params: per-system parameters, each with leading dim B (e.g. "A": (B, n, n), "C": (B, m, n),
        "Q": (B, n, n), "R": (B, m, m)); what a predictor that knows the system may use.
    family: name of the family that made it ("" for user data); its state_space(params) describes the systems.
    """

    y: Tensor
    u: Tensor | None = None
    x: Tensor | None = None
    params: dict[str, Tensor] = field(default_factory=dict)
    family: str = ""

    @property
    def num_systems(self) -> int:
        return self.y.shape[0]

    @property
    def horizon(self) -> int:
        """T: the number of steps; there are T + 1 outputs."""
        return self.y.shape[1] - 1

    @property
    def output_dim(self) -> int:
        return self.y.shape[2]

    @property
    def input_dim(self) -> int:
        return 0 if self.u is None else self.u.shape[2]

    @property
    def observed(self) -> Tensor | None:
        """(B, T+1, m) bool, True where y was measured; None when every entry was (no gaps)."""
        seen = ~torch.isnan(self.y)
        return None if bool(seen.all()) else seen

    @property
    def num_missing(self) -> int:
        """How many scalar outputs are missing (NaN in y)."""
        return int(torch.isnan(self.y).sum())

    def model_inputs(self) -> Tensor:
        """(B, T+1, m + k): [y_t, u_t] per step, the sequence a learned predictor reads (NaN where y is
        missing; mop.missing.masked_inputs gives the layout of a model with an observation mask)."""
        return self.y if self.u is None else torch.cat([self.y, self.u], dim=-1)

    def _map(self, fn: Callable[[Tensor], Tensor]) -> Trajectories:
        opt = lambda t: None if t is None else fn(t)  # noqa: E731
        return Trajectories(
            fn(self.y), opt(self.u), opt(self.x), {k: fn(v) for k, v in self.params.items()}, self.family
        )

    def to(self, device: torch.device | str) -> Trajectories:
        return self._map(lambda t: t.to(device))

    def select(self, index: slice | Tensor) -> Trajectories:
        """The subset of systems picked by `index` along the batch dimension."""
        return self._map(lambda t: t[index])

    def to_numpy_dict(self) -> dict[str, np.ndarray]:
        """Flat dict for np.savez: y, u (if any), x (if any), params as param_<name>, and family."""
        out = {"y": self.y.cpu().numpy()}
        if self.u is not None:
            out["u"] = self.u.cpu().numpy()
        if self.x is not None:
            out["x"] = self.x.cpu().numpy()
        out.update({f"param_{k}": v.cpu().numpy() for k, v in self.params.items()})
        if self.family:
            out["family"] = np.array(self.family)
        return out


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


Transition = Callable[
    [Tensor, "Tensor | None", int], Tensor
]  # (x (B, N, n), u (B, N, k) | None, t) -> (B, N, n)
TransitionJacobian = Callable[
    [Tensor, "Tensor | None", int], Tensor
]  # (x (B, n), u (B, k) | None, t) -> (B, n, n)
Projection = Callable[[Tensor], Tensor]  # x (..., n) -> (..., n), e.g. clipping to bounds


@dataclass(frozen=True)
class StateSpace:
    """The model a filter that knows the system is given, batched over B systems (float64):

        x_{t+1} = project(f(x_t, u_t, t) + w_t),  w_t ~ N(0, Q);   y_t = C_t x_t + v_t,  v_t ~ N(0, R);
        x_0 ~ N(m0, P0) (then projected).

    f maps point sets x (B, N, n) (N = 1 for a mean, N particles or sigma points) with u (B, N, k) | None.
    jacobian: df/dx at x (B, n), u (B, k) | None -> (B, n, n); None means autograd (torch.func.jacrev).
    C: (B, m, n), or a function t -> (B, m, n) for time-varying outputs (switching systems).
    project: the simulator's state projection (the quadrotor's clipping); None for none.
    """

    f: Transition
    C: Tensor | Callable[[int], Tensor]
    Q: Tensor
    R: Tensor
    m0: Tensor
    P0: Tensor
    jacobian: TransitionJacobian | None = None
    project: Projection | None = None

    def output_matrix(self, t: int) -> Tensor:
        return self.C(t) if callable(self.C) else self.C

    def transition_jacobian(self, x: Tensor, u: Tensor | None, t: int) -> Tensor:
        """(B, n, n) df/dx at x (B, n): the family's, or autograd through f. Each system's next state depends
        on its own state only, so the Jacobian of sum_b f(x_b) with respect to x_b is system b's."""
        if self.jacobian is not None:
            return self.jacobian(x, u, t)
        u_set = None if u is None else u[:, None]
        summed = torch.func.jacrev(lambda z: self.f(z[:, None], u_set, t)[:, 0].sum(0))(x)  # (n, B, n)
        return summed.permute(1, 0, 2)


def linear_state_space(
    A: Tensor,
    C: Tensor,
    Q: Tensor,
    R: Tensor,
    P0: Tensor,
    B: Tensor | None = None,
    m0: Tensor | None = None,
) -> StateSpace:
    """x_{t+1} = A x_t + B u_t + w_t, y_t = C x_t + v_t, x_0 ~ N(m0, P0) (m0 default 0); float64.

    A (B, n, n), C (B, m, n), Q (B, n, n), R (B, m, m), P0 (B, n, n), B (B, n, k) or None (no inputs: the
    inputs, if any, do not act on the state), m0 (B, n) or None."""
    A, C, Q, R, P0 = (M.double() for M in (A, C, Q, R, P0))
    Bu = None if B is None else B.double()

    def f(x: Tensor, u: Tensor | None, t: int) -> Tensor:
        if Bu is None or u is None:
            return x @ A.mT
        return x @ A.mT + u @ Bu.mT  # (B, N, n)

    return StateSpace(
        f=f,
        C=C,
        Q=Q,
        R=R,
        m0=A.new_zeros(A.shape[:-1]) if m0 is None else m0.double(),
        P0=P0,
        jacobian=lambda x, u, t: A,
    )


LINEAR_MODEL_ARRAYS = ("A", "C", "Q", "R")  # required; optional: "B", "P0", "x0_mean"


def linear_model_from_params(params: dict[str, Tensor]) -> StateSpace:
    """A known linear-Gaussian model x_{t+1} = A x_t + B u_t + w_t, y_t = C x_t + v_t, x_0 ~ N(x0_mean, P0),
    from params "A" (B, n, n), "C" (B, m, n), "Q" (B, n, n), "R" (B, m, m) and optional "B" (B, n, k)
    (default: the inputs do not act), "P0" (B, n, n) (default I), "x0_mean" (B, n) (default 0).
    MopError naming the first missing or misshapen array (as param_<name>, the .npz key)."""
    missing = [f"param_{k}" for k in LINEAR_MODEL_ARRAYS if k not in params]
    if missing:
        raise MopError(f"a linear model needs {', '.join(missing)}; add them (see mop predict --help)")
    A = params["A"]
    if A.ndim != 3 or A.shape[1] != A.shape[2]:
        raise MopError(f"param_A has shape {tuple(A.shape)}, need (B, n, n)")
    batch, n, m = A.shape[0], A.shape[-1], params["C"].shape[-2]
    eye = torch.eye(n, dtype=torch.float64, device=A.device).expand(batch, n, n)
    P0 = params.get("P0", eye)
    x0 = params.get("x0_mean", A.new_zeros(batch, n))
    B = params.get("B")
    expected = {"C": (batch, m, n), "Q": (batch, n, n), "R": (batch, m, m), "P0": (batch, n, n)}
    expected["x0_mean"] = (batch, n)
    if B is not None:
        expected["B"] = (batch, n, B.shape[-1])
    values = {"C": params["C"], "Q": params["Q"], "R": params["R"], "P0": P0, "x0_mean": x0, "B": B}
    for name, shape in expected.items():
        if tuple(values[name].shape) != shape:
            raise MopError(
                f"param_{name} has shape {tuple(values[name].shape)}, need {shape} for A {n} x {n}"
            )
    return linear_state_space(A, params["C"], params["Q"], params["R"], P0, B, x0)


class SystemFamily:
    """A distribution over dynamical systems (D_sys in the paper), batched and seeded.

    One call samples or simulates B systems at once, on any device, and all randomness comes from the
    torch.Generator passed in (same seed -> same numbers). Subclasses set state_dim, output_dim, input_dim
    in __init__ and implement sample, simulate and (for predictors that know the system) state_space.
    """

    name: ClassVar[str] = ""
    Config: ClassVar[type[SystemConfig]] = SystemConfig
    state_dim: int
    output_dim: int
    input_dim: int = 0

    def __init__(self, config: SystemConfig, dtype: torch.dtype = torch.float32) -> None:
        self.config, self.dtype = config, dtype

    def sample(self, num_systems: int, *, generator: torch.Generator) -> dict[str, Tensor]:
        """Parameters of `num_systems` systems, each tensor with leading dim B."""
        raise NotImplementedError

    def simulate(
        self, params: dict[str, Tensor], horizon: int, *, generator: torch.Generator
    ) -> Trajectories:
        """One trajectory of `horizon` steps (horizon + 1 outputs) per system."""
        raise NotImplementedError

    @staticmethod
    def state_space(params: dict[str, Tensor]) -> StateSpace:
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
    """Class decorator: register a SystemFamily subclass under `name` with its config dataclass.

    default: the family a config without a family is (SystemConfig(), a RunConfig's default system); one
    family is (mop.systems.linear).
    """

    def decorate(cls: type) -> type:
        cls.name, cls.Config = name, config
        FAMILIES.add(name, cls, default=default)
        return cls

    return decorate


def config_class(family: str) -> type[SystemConfig]:
    return FAMILIES.get(family).Config


def state_space_of(traj: Trajectories) -> StateSpace:
    """The StateSpace of the systems in `traj` from its family; for data without a family but with the
    arrays A, C, Q, R (a known linear model, linear_model_from_params), that model; else MopError."""
    if not traj.family and all(k in traj.params for k in LINEAR_MODEL_ARRAYS):
        return linear_model_from_params(traj.params)
    if not traj.family:
        raise MopError(
            "these trajectories carry no system family, so a predictor that knows the system cannot run; "
            "use one that needs no model (`mop predict --help` lists them)"
        )
    return FAMILIES.get(traj.family).state_space(traj.params)


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

    params = {k: put(v, new.params[k]) for k, v in traj.params.items()}
    return Trajectories(put(traj.y, new.y), put(traj.u, new.u), put(traj.x, new.x), params, traj.family)


def cast(traj: Trajectories, dtype: torch.dtype) -> Trajectories:
    """Floating tensors to dtype (integer params such as switch_time stay as they are)."""
    return traj._map(lambda t: t.to(dtype) if t.is_floating_point() else t)
