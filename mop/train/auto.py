"""model.features = "auto": the online-identifier input feature chosen from the family's shapes and data.

    config = resolve_features(config)      # auto -> the explicit keys (input_scale, rls_order, arx_order)
    describe_features(config.model)        # "ARX(1, 2)", "running scale + RLS-AR(3)", "none"

The rule (choose_features), read off N = AUTO_SYSTEMS trajectories of the family simulated with a fixed
seed (AUTO_SEED, apart from every training and test stream), y (N, T+1, m) and u (N, T+1, k):
- the identifier: ARX(p, q) (mop.filters.arx) where there are inputs (k > 0), RLS-AR(p) (mop.filters.rls)
  where there are none; none where training drops outputs (the feature reads y_t, which a gap zero-fills);
- its orders: the (p, q) of ORDERS_ARX (p of ORDERS_AR) whose online one-step predictions have the lowest
  MSE over t in [ORDER_WINDOW_START, T] on those trajectories (best_orders): the order a user would pick by
  running the identifiers on a sample of the family;
- the identifier's prior (family_prior), where there are inputs: its recursion starts from theta_0 and P_0
  read off another AUTO_SYSTEMS trajectories of PRIOR_HORIZON * T steps (seed PRIOR_SEED): each system's
  least-squares coefficients, their mean and their covariance over the residual variance, i.e. the
  empirical-Bayes Gaussian prior of the family's coefficients, so from its first pairs the feature is the
  posterior mean (model.rls_prior, model.rls_prior_cov; the orders are scored started from their own prior).
  Measured on the identifier alone, MSE ratio to the KF over t in [20, 50], N = 500 (without the prior, then
  with it): two-mass 1.99 -> 1.29, dead-time 1.75 -> 1.39, rlc-circuit 1.32 -> 1.17, thermal-network 1.45 ->
  1.22, linear-inputs 1.31 -> 1.24, linear 1.06 -> 1.04 (AR(2)), upper-triangular 1.38 -> 1.34, colored-
  noise 2.19 (AR(2)) -> 1.61 (AR(4)); on the output-only families the model trained on it did not follow
  (colored-noise 1.201 -> 1.392 x the exact optimum), so they keep the paper's start;
- a mixture of MIXTURE_SIZE Gaussians in place of the one (mop.filters.mixture: the identifier's K
  recursions weighed by their evidence), fitted by EM to the least-squares coefficients of MIXTURE_SYSTEMS
  other systems (seed MIXTURE_SEED), where it cuts the identifier's error on the scored trajectories by more
  than MIXTURE_GAIN (3%): where the family's coefficients are far from one Gaussian. Its K recursions cost
  1.3-1.5x the identifier's step (STEP_COST), so the model gets fewer steps. Measured (the identifier's error
  with 16 components over one Gaussian's, on the scored trajectories; then MOP / KF over t in [20, 50],
  seed 0, one Gaussian at 2100 steps -> the mixture at 1700, the same 500 test systems; docs/results has the
  shipped rule's runs, 1500 steps, seeds 0 / 1): dead-time 0.907,
  1.384 -> 1.267 (a dead time of 1-3 samples puts the input's weight on different lags); rlc-circuit
  0.950, 1.108 -> 1.094; thermal-network 0.959, 1.145 -> 1.129; two-mass 0.971, 1.141 -> 1.142;
  pendulum 0.972; quadrotor 0.987; linear-inputs 1.002. So the rule takes it where the identifier gains
  more than 3% (dead-time, rlc-circuit, thermal-network);
- the family's units (family_units), first: where some output (input) channel's median RMS over systems
  is outside [1 / SCALE_FAR, SCALE_FAR], a family written in other units, the model reads every output
  (input) channel divided by its median RMS (model.output_units, model.input_units; its predictions are
  multiplied back, mop.models.normalization), and the rest of the rule reads the sample in those units. No
  built-in or example family is that far (channel medians 0.26 to 4.7), so they read their data as
  simulated; the thermal network written 30x larger and 30x smaller gets the same keys at either size;
- the running output scale (mop.models.features) where the outputs are far from unit scale: the per-system
  RMS of y, s_i = sqrt(mean_t ||y_t||^2 / m), has a median outside [1 / SCALE_FAR, SCALE_FAR] or a ratio of
  its 90% to its 10% quantile above SCALE_SPREAD (scale_far_from_unit), in the family's units.
Measured on the built-in families (256 systems, T = 50): q90 / q10 of s is 2.3 (quadrotor) to 3.7
(linear-inputs) for every family whose plain model reads y as is, and 6.3 on upper-triangular, the one
whose model needed the scale (MOP/KF 4.29 plain, 3.45 with it); medians 0.6 (rlc-circuit) to 5.0
(quadrotor). The chosen orders (ratio of the identifier's MSE to the KF's over t in [20, 50]): linear
AR(1) 1.062 (AR(2) 1.084), colored-noise AR(2), upper-triangular AR(3) 1.382 (AR(2) 1.431),
linear-inputs ARX(1, 2) 1.307 (ARX(2, 2) 1.407), quadrotor ARX(3, 1), rlc-circuit ARX(2, 2) 1.324.

The step budget follows the step cost: with a feature on, train.steps becomes steps / cost rounded to two
significant digits, cost the product of the STEP_COST factors of the features chosen, so the training
takes the plain model's time (as the quadrotor's 2100 steps for its 2500 did by hand). The budget of a
preset or an experiment is in plain-model steps; a train.steps given on the command line is taken as is.
Recorded data (data.path) and architectures that read no features (the GRU) keep the given keys.
"""

from __future__ import annotations

import dataclasses
import functools
import json

import torch
from torch import Tensor

from mop.config import ModelConfig, RunConfig, SystemConfig, from_dict
from mop.errors import MopError
from mop.filters.arx import arx_predict, arx_regressors
from mop.filters.mixture import MixturePrior, fit_mixture, mixture_predict
from mop.filters.rls import Prior
from mop.models import reads_features
from mop.systems import generator, make_family

AUTO_SEED = 4_000_037  # the trajectories the rule reads: apart from training (seed), validation and test
AUTO_SYSTEMS = 256
PRIOR_SEED = AUTO_SEED + 1  # the trajectories the feature's prior is fitted on, apart from the scored ones
PRIOR_HORIZON = 4  # ... of 4 T steps each, so each system's least-squares fit is close to its own ARX
PRIOR_RIDGE = 1e-6  # P_0 + 1e-6 mean(diag P_0) I: positive definite where a coefficient never varies
MIXTURE_SEED = AUTO_SEED + 2  # the trajectories the mixture prior is fitted on
MIXTURE_SYSTEMS = 2048  # ... of PRIOR_HORIZON * T steps: K components need more systems than one Gaussian
MIXTURE_SIZE = 16  # the mixture prior's components, where it wins (MIXTURE_GAIN)
MIXTURE_GAIN = 0.03  # taken where the identifier's error falls by more than 3% against one Gaussian
ORDER_WINDOW_START = 20  # the orders' error window starts here (at T // 2 for T < 40)
ORDERS_AR = (1, 2, 3, 4)
ORDERS_ARX = tuple((p, q) for p in (1, 2, 3, 4) for q in range(1, 7))  # q up to 6: input dead time
SCALE_FAR = 10.0  # median per-system RMS of y outside [1 / 10, 10]: far from unit scale
SCALE_SPREAD = 5.0  # q90 / q10 of the per-system RMS above 5: sizes too different for one network scale
# Training-step cost of a feature relative to the plain model's (small preset, one torch thread), measured
# side by side on the idle 2-core AMD EPYC: the running scale 77 against 74 ms (linear); the identifier
# 97.8 against 83.7 ms (quadrotor, ARX(2, 2)). One factor serves RLS-AR and ARX: both run the same recursion
# (mop.filters.rls.rls_loop), whose own time (4.2 to 12 ms a batch for d = 2 to 15 regressors, T = 50,
# batch 64) is small against the step.
# The mixture prior's 16 recursions (mop.filters.mixture) on top of one Gaussian's, `mop bench features`
# on the idle 2-core AMD EPYC (20 rounds): dead-time ARX(3, 6), m = 1: 1.29 and 1.32 (89.3 against 69.4,
# 100.7 against 76.3 ms); rlc-circuit ARX(3, 3), m = 2: 1.51 (103.5 against 68.6); thermal-network ARX(4, 6),
# m = 2: 1.53 (124.7 against 81.6). One factor, 1.4, is within 10% of each.
STEP_COST = {"scale": 77 / 74, "identifier": 97.8 / 83.7}
STEP_COST["mixture"] = STEP_COST["identifier"] * 1.4
FEATURE_KEYS = (
    "input_scale",
    "rls_order",
    "arx_order",
    "rls_offset",
    "rls_prior",
    "rls_prior_cov",
    "rls_p0",
    "rls_prior_weights",
    "rls_prior_noise",
)


@dataclasses.dataclass(frozen=True)
class FeatureChoice:
    """What auto picks: the running scale on or off, the identifier's output order p (0 = none), input
    order q (0 = output-only RLS-AR(p)), and its prior: theta_0 (d rows of m, flat) and P_0 (d x d, flat),
    empty without one; a mixture prior (mop.filters.mixture): K blocks of each, the K weights and the
    noise variance sigma^2 that weighs them (empty and 0 for one Gaussian); the family's units of the
    outputs and of the inputs (family_units; empty: as simulated), in which all of it was chosen."""

    scale: bool = False
    order: int = 0
    input_order: int = 0
    prior_theta: tuple[float, ...] = ()
    prior_cov: tuple[float, ...] = ()
    prior_weights: tuple[float, ...] = ()
    prior_noise: float = 0.0
    output_units: tuple[float, ...] = ()
    input_units: tuple[float, ...] = ()

    @property
    def cost(self) -> float:
        """The step cost relative to the plain model's (STEP_COST)."""
        identifier = STEP_COST["mixture" if self.prior_weights else "identifier"] if self.order else 1.0
        return (STEP_COST["scale"] if self.scale else 1.0) * identifier


def scale_far_from_unit(y: Tensor) -> bool:
    """Whether outputs y (N, T+1, m) are far from unit scale (the module docstring's rule)."""
    rms = y.double().pow(2).mean((1, 2)).sqrt()  # (N,)
    q10, q50, q90 = torch.quantile(rms, torch.tensor([0.1, 0.5, 0.9], dtype=rms.dtype)).tolist()
    return not (1 / SCALE_FAR <= q50 <= SCALE_FAR) or q90 > SCALE_SPREAD * max(q10, 1e-12)


def family_units(signal: Tensor | None) -> tuple[float, ...]:
    """The units of a signal y or u (N, T+1, c) of the family's sample: each channel's median over systems
    of its RMS, where some channel's is outside [1 / SCALE_FAR, SCALE_FAR] (a family written in other
    units); () where every channel is near unit scale, or there is no signal."""
    if signal is None:
        return ()
    rms = signal.double().pow(2).mean(1).sqrt().median(0).values  # (c,)
    if bool(((rms >= 1 / SCALE_FAR) & (rms <= SCALE_FAR)).all()):
        return ()
    return tuple(rms.clamp_min(1e-12).tolist())


def in_units(signal: Tensor | None, units: tuple[float, ...]) -> Tensor | None:
    """signal (N, T+1, c) / units (c,) (unchanged for ())."""
    if signal is None or not units:
        return signal
    return signal / torch.tensor(units, dtype=signal.dtype)


def system_coefficients(y: Tensor, u: Tensor | None, p: int, q: int) -> tuple[Tensor, Tensor]:
    """(theta (N, d, m), sigma^2): each system's least-squares ARX(p, q) (RLS-AR(p) for q = 0 or u None)
    coefficients over its pairs (phi_{s-1}, y_s), s >= r = max(p, q) (the pairs the recursion reads), from
    y (N, T+1, m), u (N, T+1, k)|None, and the residuals' mean square over all systems."""
    y = y.double()
    u = None if u is None or q == 0 else u.double()
    r = p if u is None else max(p, q)
    phi = arx_regressors(y, u, p, max(q, 1))  # (N, T+1, d)
    X, Y = phi[:, r - 1 : -1], y[:, r:]  # (N, T+1-r, d), (N, T+1-r, m)
    theta = torch.linalg.lstsq(X, Y, driver="gelsd").solution  # (N, d, m); minimum norm where rank-deficient
    return theta, (Y - X @ theta).pow(2).mean().clamp_min(1e-12)


def family_mixture(y: Tensor, u: Tensor | None, p: int, q: int, size: int = MIXTURE_SIZE) -> MixturePrior:
    """The family's mixture prior of the ARX(p, q) coefficients: mop.filters.mixture.fit_mixture of `size`
    components to each system's least-squares coefficients (system_coefficients) of y (N, T+1, m), u."""
    theta, sigma2 = system_coefficients(y, u, p, q)
    return fit_mixture(theta, float(sigma2), size, PRIOR_RIDGE)


def family_prior(y: Tensor, u: Tensor | None, p: int, q: int) -> Prior:
    """The family's empirical-Bayes prior of the ARX(p, q) (RLS-AR(p) for q = 0) coefficients, from
    trajectories y (N, T+1, m), u (N, T+1, k)|None of N systems: each system's least-squares coefficients
    theta_i (d, m) over its pairs (phi_{s-1}, y_s), s >= r = max(p, q) (the pairs the recursion reads);
    theta_0 their mean, P_0 their covariance (pooled over the m outputs) over sigma^2, the residuals' mean
    square: the recursion's P is the coefficients' covariance in units of the noise variance
    (mop.filters.rls.initial_state), so it then returns the posterior mean under theta ~ N(theta_0, C)."""
    theta, sigma2 = system_coefficients(y, u, p, q)
    dev = theta - theta.mean(0)
    cov = torch.einsum("nim,njm->ij", dev, dev) / (dev.shape[0] * dev.shape[2]) / sigma2
    cov = cov + PRIOR_RIDGE * cov.diagonal().mean() * torch.eye(cov.shape[0], dtype=cov.dtype)
    return theta.mean(0), 0.5 * (cov + cov.T)


def identifier_error(
    y: Tensor, u: Tensor | None, p: int, q: int, start: int, prior: Prior | MixturePrior | None
) -> float:
    """MSE of the online RLS-AR(p) (q = 0) or ARX(p, q) one-step predictions of y_t over t >= start, the
    recursion started from prior (a MixturePrior: mop.filters.mixture)."""
    if isinstance(prior, MixturePrior):
        yhat = mixture_predict(y, None if q == 0 else u, p, q, prior)
    else:
        yhat = arx_predict(y, None if q == 0 else u, p, max(q, 1), False, prior)
    return float((yhat[:, start:] - y[:, start:]).pow(2).sum(-1).mean())


def best_orders(
    y: Tensor, u: Tensor | None, fit: tuple[Tensor, Tensor | None] | None
) -> tuple[int, int, Prior | None]:
    """(p, q, prior) of the identifier with the lowest error over t >= ORDER_WINDOW_START on y (N, T+1, m)
    and u (N, T+1, k) or None (q = 0: RLS-AR(p)), each order started from its family_prior fitted on the
    other trajectories fit = (y, u) (None: from the paper's theta_0 = 0, P_0 = I, prior None); the first of
    the grid on a tie."""
    start = min(ORDER_WINDOW_START, y.shape[1] // 2)
    grid = [(p, 0) for p in ORDERS_AR] if u is None else list(ORDERS_ARX)
    y, u = y.double(), None if u is None else u.double()
    priors = [None if fit is None else family_prior(*fit, p, q) for p, q in grid]
    errors = [identifier_error(y, u, p, q, start, prior) for (p, q), prior in zip(grid, priors, strict=True)]
    best = min(range(len(grid)), key=errors.__getitem__)
    return *grid[best], priors[best]


def choose_features(
    y: Tensor,
    u: Tensor | None,
    fit: tuple[Tensor, Tensor | None] | None,
    drops_outputs: bool = False,
    mixture_fit: tuple[Tensor, Tensor | None] | None = None,
) -> FeatureChoice:
    """The rule: y (N, T+1, m), u (N, T+1, k) or None (no inputs), the prior's trajectories fit = (y, u)
    (N', T'+1, ...; None: no prior) -> FeatureChoice. The family's prior where there are inputs (ARX)
    only: on output-only families it improved the identifier but not the model trained on it
    (colored-noise, small preset, seed 0: the RLS-AR(4) feature from the prior 1.61 x the exact optimum
    against RLS-AR(2)'s 2.19 without, yet MOP 1.392 against 1.201)."""
    scale = scale_far_from_unit(y)
    if drops_outputs:
        return FeatureChoice(scale=scale)
    p, q, prior = best_orders(y, u, None if u is None else fit)
    if prior is None:
        return FeatureChoice(scale, p, q)
    if mixture_fit is not None:
        mixture = family_mixture(*mixture_fit, p, q)
        start = min(ORDER_WINDOW_START, y.shape[1] // 2)
        single, mixed = (identifier_error(y.double(), u.double(), p, q, start, pr) for pr in (prior, mixture))
        if mixed < (1 - MIXTURE_GAIN) * single:
            flat = lambda a: tuple(a.flatten().tolist())  # noqa: E731
            weights, noise = flat(mixture.weights), mixture.noise
            return FeatureChoice(scale, p, q, flat(mixture.means), flat(mixture.covs), weights, noise)
    theta, cov = prior
    return FeatureChoice(scale, p, q, tuple(theta.flatten().tolist()), tuple(cov.flatten().tolist()))


@functools.lru_cache(maxsize=32)
def _family_choice(system_json: str, horizon: int, drops_outputs: bool) -> FeatureChoice:
    family = make_family(from_dict(SystemConfig, json.loads(system_json)), dtype=torch.float64)
    traj = family.generate(AUTO_SYSTEMS, horizon, generator=generator(AUTO_SEED))
    y_units, u_units = family_units(traj.y), family_units(traj.u)
    scaled = lambda y, u: (in_units(y, y_units), in_units(u, u_units))  # noqa: E731  the model's units
    needs_prior = traj.u is not None and not drops_outputs  # choose_features: the prior where ARX is chosen
    fit = scaled(*_prior_sample(system_json, horizon)) if needs_prior else None
    mixture_fit = None
    if needs_prior:
        mixture_fit = scaled(*_prior_sample(system_json, horizon, MIXTURE_SYSTEMS, MIXTURE_SEED))
    choice = choose_features(*scaled(traj.y, traj.u), fit, drops_outputs, mixture_fit)
    return dataclasses.replace(choice, output_units=y_units, input_units=u_units)


@functools.lru_cache(maxsize=32)
def _prior_sample(
    system_json: str, horizon: int, systems: int = AUTO_SYSTEMS, seed: int = PRIOR_SEED
) -> tuple[Tensor, Tensor | None]:
    """(y, u) of the `systems` trajectories of PRIOR_HORIZON * horizon steps a prior is fitted on."""
    family = make_family(from_dict(SystemConfig, json.loads(system_json)), dtype=torch.float64)
    fit = family.generate(systems, PRIOR_HORIZON * horizon, generator=generator(seed))
    return fit.y, fit.u


def _given_prior(system_json: str, horizon: int, p: int, q: int) -> tuple[tuple[float, ...], ...]:
    theta, cov = family_prior(*_prior_sample(system_json, horizon), p, q)
    return tuple(theta.flatten().tolist()), tuple(cov.flatten().tolist())


def resolve_family_prior(config: RunConfig) -> RunConfig:
    """config with model.rls_prior = "family" replaced by the family's prior (family_prior) of the given
    orders, fitted on AUTO_SYSTEMS trajectories of PRIOR_HORIZON * T steps, and "mixture" by its mixture
    prior of MIXTURE_SIZE components (family_mixture, on MIXTURE_SYSTEMS trajectories); others unchanged.
    The train.steps given are kept (a named key is taken as written)."""
    model = config.model
    if model.rls_prior not in ("family", "mixture"):
        return config
    if config.data is not None or model.rls_offset or model.rls_order == 0:
        raise MopError(
            f"model.rls_prior={model.rls_prior} is a prior of a system family's ARX / RLS-AR coefficients: "
            "it needs model.rls_order > 0, no rls_offset and no data file (on recorded data use "
            "model.rls_prior=fit)"
        )
    system = json.dumps(dataclasses.asdict(config.system), sort_keys=True)
    p, q = model.rls_order, model.arx_order
    if model.rls_prior == "mixture":
        prior = _given_mixture(system, config.train.horizon, p, q)
        model = dataclasses.replace(
            model,
            rls_prior=prior.means.flatten().tolist(),
            rls_prior_cov=prior.covs.flatten().tolist(),
            rls_prior_weights=prior.weights.tolist(),
            rls_prior_noise=prior.noise,
        )
    else:
        theta, cov = _given_prior(system, config.train.horizon, p, q)
        model = dataclasses.replace(model, rls_prior=list(theta), rls_prior_cov=list(cov))
    return dataclasses.replace(config, model=model)


@functools.lru_cache(maxsize=32)
def _given_mixture(system_json: str, horizon: int, p: int, q: int) -> MixturePrior:
    sample = _prior_sample(system_json, horizon, MIXTURE_SYSTEMS, MIXTURE_SEED)
    return family_mixture(*sample, p, q)


def family_choice(config: RunConfig) -> FeatureChoice:
    """choose_features on AUTO_SYSTEMS trajectories of config's family (cached per system config)."""
    system = json.dumps(dataclasses.asdict(config.system), sort_keys=True)
    return _family_choice(system, config.train.horizon, config.train.drops_outputs)


def steps_for(steps: int, cost: float) -> int:
    """steps / cost to two significant digits (2500 / 1.17 -> 2100), at least 1; steps when cost is 1."""
    return steps if cost == 1.0 else max(1, int(float(f"{steps / cost:.2g}")))


def apply_choice(config: RunConfig, choice: FeatureChoice, scale_steps: bool = True) -> RunConfig:
    """config with model.features = "given", the choice's keys and (scale_steps) train.steps for its step
    cost."""
    model = dataclasses.replace(
        config.model,
        features="given",
        input_scale="running" if choice.scale else "none",
        rls_order=choice.order,
        arx_order=choice.input_order,
        rls_offset=False,
        rls_prior=list(choice.prior_theta) if choice.prior_theta else "none",
        rls_prior_cov=list(choice.prior_cov) if choice.prior_cov else None,
        rls_prior_weights=list(choice.prior_weights) if choice.prior_weights else None,
        rls_prior_noise=choice.prior_noise,
        output_units=list(choice.output_units) if choice.output_units else None,
        input_units=list(choice.input_units) if choice.input_units else None,
    )
    steps = steps_for(config.train.steps, choice.cost) if scale_steps else config.train.steps
    train = dataclasses.replace(config.train, steps=steps)
    return dataclasses.replace(config, model=model, train=train)


def resolve_features(config: RunConfig, scale_steps: bool = True) -> RunConfig:
    """config with model.features = "auto" resolved (the module docstring); others unchanged.
    scale_steps=False keeps train.steps as it is (a number of steps the user gave on the command line)."""
    if config.model.features != "auto":
        return resolve_family_prior(config)
    if config.data is not None or not reads_features(config.model.arch):
        return dataclasses.replace(config, model=dataclasses.replace(config.model, features="given"))
    return apply_choice(config, family_choice(config), scale_steps)


def for_arch(config: RunConfig, arch: str) -> RunConfig:
    """config trained as architecture `arch`: one that reads no features gets the feature keys off."""
    model = dataclasses.replace(config.model, arch=arch)
    if not reads_features(arch):
        off = {key: ModelConfig.__dataclass_fields__[key].default for key in FEATURE_KEYS}
        model = dataclasses.replace(model, **off)
    return dataclasses.replace(config, model=model)


def describe_features(model: ModelConfig) -> str:
    """The model's input features in words: "running scale + ARX(1, 2)", "RLS-AR(3)", "none"."""
    parts = ["running scale"] if model.input_scale == "running" else []
    if model.rls_order and model.arx_order:
        parts.append(f"ARX({model.rls_order}, {model.arx_order})")
    elif model.rls_order:
        parts.append(f"RLS-AR({model.rls_order})")
    prior = ", family prior" if model.rls_prior == "family" or model.rls_prior_cov is not None else ""
    if model.rls_prior == "mixture":
        prior = f", family prior of {MIXTURE_SIZE} components"
    elif model.rls_prior_weights is not None:
        prior = f", family prior of {len(model.rls_prior_weights)} components"
    return " + ".join(parts) + prior if parts else "none"
