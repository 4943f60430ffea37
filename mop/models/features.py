"""Causal input features of the learned models: a running output scale and an RLS one-step prediction.

Both are options of ModelConfig (off by default, so the paper's model is unchanged) and are computed by the
model's front end (mop.models.frontend) from its inputs z_t = [y_t, u_t] (B, T, d_in), the first m channels
being y_t; position t sees z_0..z_t only, so the model stays causal and LearnedPredictor needs nothing new.

model.input_scale = "running" (causal per-trajectory normalisation):
    s_t = sqrt(eps + (1 / (t+1)) sum_{tau <= t} ||y_tau||^2 / m)          (B, T, 1), eps = SCALE_EPS
    the model reads [y_t / s_t, u_t, log s_t] and its mean read-out is multiplied back: yhat_{t+1} = s_t out_t
    (a Gaussian read-out's variance by s_t^2). Systems whose outputs differ in size by orders of magnitude
    (upper-triangular A: the per-system RMS of y spans a factor of 44) then look alike to the network.
model.rls_order = p > 0 (the RLS feature):
    r_{t+1} = the matrix RLS-AR(p) prediction of y_{t+1} from y_0..y_t (mop.filters.rls, the paper's baseline
    for p = 2); with model.arx_order = q > 0 the ARX(p, q) prediction from y_0..y_t and u_0..u_t
    (mop.filters.arx: the regressors also hold u_t..u_{t-q+1}, for systems driven by inputs); fed in as m
    extra channels (divided by s_t with the running scale), and the read-out predicts the residual:
    yhat_{t+1} = r_{t+1} + s_t out_t. At initialisation (small read-out weights) the model is
    the RLS predictor, so training starts from it rather than from zero.
    model.rls_offset = true adds a constant regressor (mop.filters.arx's offset, an intercept), for outputs
    with an offset such as the sysid benchmarks' per-sequence mean removal.
    model.rls_cubes = c > 0 adds the cubes of the first c output lags y_t^3..y_{t-c+1}^3 to the regressors
    (a cubic NARX fitted in context: the restoring force of a Duffing oscillator such as Silverbox); the
    records recipe chooses c by held-out simulation (mop.identify.cubic). With record_norm the cubes are of
    the outputs in the feature's fixed frame (feature_frame), so the feature stays equivariant to units.

model.record_norm = "causal" (mop.models.recordnorm): every output and input channel normalised by its
    causal running mean and std, the read-out mapped back: yhat_{t+1} = b_t + std_t(y) out_t, b_t the running
    mean of y (or the RLS feature, which the network then reads normalised alike); no extra channel.
model.residual_scale = "running" (with record_norm and the feature): the correction is scaled by the
    feature's own recent one-step error instead of std_t(y): yhat_{t+1} = r_{t+1} + c_t out_t with
    c_t = sqrt(v_t + RESIDUAL_FLOOR std_t(y)^2), v_t the exponentially weighted mean of (y_s - r_s)^2 over
    the measured s <= t, the error k measured steps back weighted model.residual_decay^k (before the first:
    std_t(y)^2), and the network also reads log(c_t / std_t(y)). Where the feature is exact (a noise-free
    linear record) c_t falls to the floor once the feature's start-up errors are forgotten (a factor 0.5 per
    step: within ~20 steps; at 0.9 the LTI model's one-step RMSE over t in [50, 60) was 0.016 against the
    feature's 0.0006), and so does the network's error; across a gap v_t keeps its last value.
    model.residual_scale = "measured": the same where y_t is measured, and std_t(y) at positions that read
    a missing y_t (a simulated tail), where the feature's last one-step error says little about the
    simulation's (on the noisy nonlinear classes, "running" cost simulation accuracy).
With model.observation_mask the RLS feature reads the missing outputs as missing (mop.filters.arx's gaps:
filled with its own predictions, no update), so across a gap of outputs it is the ARX simulation.

In a sliding window (trajectories longer than model.context, LearnedPredictor mode "window") both features
restart with each window, exactly as the network's attention does. Streaming (FeatureState) keeps them over
the whole stream: equal to the forward inside the context, beyond it the running sums and the RLS fit cover
every step so far (the KV cache is the rolling approximation documented in mop.models.transformer anyway).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from mop.config import ModelConfig
from mop.errors import MopError
from mop.filters.arx import arx_predict
from mop.filters.mixture import MixturePrior, MixtureState, mixture_predict
from mop.filters.rls import Prior, initial_state, regressors, rls_update
from mop.models.recordnorm import RecordStats, normalise, running_moments

# P_0 of the RLS / ARX feature started from fitted coefficients (model.rls_prior): a window's 50 pairs of
# unit-scale regressors move it little (the ridge term P_0^-1 = 1000 I against sum phi phi^T ~ 50 I), so the
# feature is the fitted ARX, nudged by each window
PRIOR_P0 = 1e-3
# record_norm's pseudo-steps (model.record_prior_steps) of a class model that reads a feature fitted on an
# estimation record: the record is in that record's normalised units, so its scale is known from step 0
FITTED_PRIOR_STEPS = 100
SCALE_EPS = 1e-4  # floor of s_t^2: a trajectory of zeros gets s = 0.01, not a division by zero
RESIDUAL_FLOOR = 1e-8  # c_t^2 >= 1e-8 std_t(y)^2: the correction's scale is at least 1e-4 of the record's


def extra_input_dim(cfg: ModelConfig) -> int:  # record_norm adds none
    """Channels added to the model's input: 1 (log s_t) with the running scale, m with the RLS feature, m
    more (log c_t / std_t) with the residual scale."""
    scale = 1 if cfg.input_scale == "running" else 0
    residual = cfg.output_dim if cfg.residual_scale != "none" else 0
    return scale + (cfg.output_dim if cfg.rls_order > 0 else 0) + residual


def running_scale(y: Tensor) -> Tensor:
    """s_t = sqrt(eps + mean_{tau <= t} ||y_tau||^2 / m): y (B, T, m) -> (B, T, 1)."""
    count = torch.arange(1, y.shape[1] + 1, device=y.device, dtype=y.dtype)[None, :, None]  # (1, T, 1)
    mean_sq = (y**2).mean(-1, keepdim=True).cumsum(1) / count  # (B, T, 1)
    return (mean_sq + SCALE_EPS).sqrt()


def input_count(cfg: ModelConfig) -> int:
    """k, the number of inputs u in the model's input layout [y, u] (+ the mask's m channels)."""
    return cfg.input_dim - cfg.output_dim * (2 if cfg.observation_mask else 1)


def regressor_count(cfg: ModelConfig) -> int:
    """d = p m + c m + q k (+ 1 with rls_offset): the RLS / ARX feature's regressors (mop.filters.arx's
    order; c = model.rls_cubes)."""
    return (
        (cfg.rls_order + cfg.rls_cubes) * cfg.output_dim
        + cfg.arx_order * input_count(cfg)
        + int(cfg.rls_offset)
    )


def check_features(cfg: ModelConfig) -> None:
    """One-line errors for feature options the model's inputs cannot serve."""
    if cfg.arx_order > 0 and input_count(cfg) <= 0:
        raise MopError("model.arx_order reads input lags, but the model has no inputs u; use rls_order alone")
    if isinstance(cfg.rls_prior, str) and cfg.rls_prior not in ("none", "fit", "family", "mixture"):
        raise MopError(
            "model.rls_prior must be 'none', 'fit', 'family', 'mixture' or a list of coefficients, "
            f"got {cfg.rls_prior!r}"
        )
    if cfg.rls_prior != "none" and cfg.rls_order == 0:
        raise MopError(
            "model.rls_prior starts the RLS / ARX feature from fitted coefficients: it needs "
            "model.rls_order > 0"
        )
    for name, count in (("output_units", cfg.output_dim), ("input_units", input_count(cfg))):
        units = getattr(cfg, name)
        if units is not None and len(units) != count:
            raise MopError(f"model.{name} needs one number per channel ({count}), got {len(units)}")
    d = regressor_count(cfg)
    listed = isinstance(cfg.rls_prior, list)
    K = prior_components(cfg)
    if cfg.rls_prior_weights is not None:
        _check_mixture(cfg, listed)
    if listed and len(cfg.rls_prior) != K * d * cfg.output_dim:
        raise MopError(
            f"model.rls_prior holds {len(cfg.rls_prior) // max(cfg.output_dim, 1)} rows of coefficients, "
            f"the feature reads {d}" + (f" in each of {K} components" if K > 1 else "")
        )
    if listed and cfg.rls_p0 != 1.0:
        raise MopError("model.rls_p0 sets P_0 without a listed model.rls_prior; use rls_prior_cov with one")
    if cfg.rls_prior_cov is not None and (not listed or len(cfg.rls_prior_cov) != K * d * d):
        raise MopError(
            f"model.rls_prior_cov is the feature's P_0, {K} x {d} x {d} = {K * d * d} numbers beside a list "
            f"model.rls_prior; got {len(cfg.rls_prior_cov)} beside rls_prior={cfg.rls_prior!r:.40}"
        )
    if cfg.record_norm != "none" and (cfg.input_scale != "none" or cfg.readout != "mean"):
        raise MopError(
            "model.record_norm normalises each record itself: use it with model.input_scale='none' and "
            "model.readout='mean' (a channel constant so far predicts its value, with no variance)"
        )


def prior_components(cfg: ModelConfig) -> int:
    """K, the components of the feature's prior: len(model.rls_prior_weights), 1 without them."""
    return 1 if cfg.rls_prior_weights is None else len(cfg.rls_prior_weights)


def _check_mixture(cfg: ModelConfig, listed: bool) -> None:
    """One-line errors for a mixture prior (mop.filters.mixture) the feature cannot run."""
    weights = cfg.rls_prior_weights
    if not weights or min(weights) < 0 or abs(sum(weights) - 1) > 1e-6:
        raise MopError(f"model.rls_prior_weights must be K >= 1 weights >= 0 summing to 1, got {weights}")
    if not listed or cfg.rls_prior_cov is None:
        raise MopError(
            "model.rls_prior_weights needs the components' coefficients (a list model.rls_prior) "
            "and their P_0 (model.rls_prior_cov)"
        )
    if cfg.rls_offset or cfg.observation_mask or cfg.record_norm != "none":
        raise MopError(
            "a mixture prior (model.rls_prior_weights) runs the ARX feature on complete outputs in their own "
            "units: use it without model.rls_offset, observation_mask and record_norm"
        )


def reads_features(cfg: ModelConfig) -> bool:
    """True when the network's inputs are functions of the whole window (running statistics, RLS)."""
    return extra_input_dim(cfg) > 0 or cfg.record_norm != "none"


def observed_outputs(inputs: Tensor, cfg: ModelConfig) -> tuple[Tensor, Tensor | None]:
    """(y (B, T, m) with NaN where missing, seen (B, T, m) bool|None) from the model's inputs (the mask
    layout [y zero-filled, u, observed] with model.observation_mask)."""
    y = inputs[..., : cfg.output_dim]
    if not cfg.observation_mask:
        return y, None
    seen = inputs[..., cfg.input_dim - cfg.output_dim :] > 0.5
    return torch.where(seen, y, torch.full_like(y, float("nan"))), seen


def gap_positions(inputs: Tensor, cfg: ModelConfig) -> Tensor | None:
    """(B, T) bool, True where position t reads a missing output (any channel), for model.gap_loss
    "balanced"; None for "pooled"."""
    if cfg.gap_loss != "balanced":
        return None
    return ~observed_outputs(inputs, cfg)[1].all(-1)


def feature_prior(cfg: ModelConfig) -> Prior | MixturePrior | None:
    """(theta_0 (d, m) float64, P_0) of the RLS / ARX feature where model.rls_prior holds the coefficients
    (d = p m + q k [+ 1] rows, in mop.filters.arx's regressor order): P_0 the (d, d) matrix
    model.rls_prior_cov, or PRIOR_P0 (times I) without it, or 0 with model.rls_fixed. Without them (None:
    theta_0 = 0, model.rls_p0) where rls_p0 is not 1, else None (the recursion's own theta_0 = 0, P_0 =
    I). With model.rls_prior_weights, the MixturePrior of those K blocks of coefficients and covariances."""
    if not isinstance(cfg.rls_prior, list):
        return None if cfg.rls_p0 == 1.0 else (None, cfg.rls_p0)
    if cfg.rls_prior_weights is not None:
        K, m = len(cfg.rls_prior_weights), cfg.output_dim
        means = torch.tensor(cfg.rls_prior, dtype=torch.float64).reshape(K, -1, m)
        covs = torch.tensor(cfg.rls_prior_cov, dtype=torch.float64).reshape(K, means.shape[1], -1)
        weights = torch.tensor(cfg.rls_prior_weights, dtype=torch.float64)
        return MixturePrior(weights, means, covs, cfg.rls_prior_noise)
    theta = torch.tensor(cfg.rls_prior, dtype=torch.float64).reshape(-1, cfg.output_dim)
    if cfg.rls_fixed:
        return theta, 0.0
    if cfg.rls_prior_cov is None:
        return theta, PRIOR_P0
    return theta, torch.tensor(cfg.rls_prior_cov, dtype=torch.float64).reshape(theta.shape[0], -1)


def rls_next(
    y: Tensor,
    order: int,
    u: Tensor | None = None,
    input_order: int = 0,
    offset: bool = False,
    prior: Prior | MixturePrior | None = None,
    updates_from: int | None = None,
    bounds_from: int = 0,
    cubes: int = 0,
    known_range: Tensor | None = None,
) -> Tensor:
    """r (B, T, m): r[:, t] is the RLS-AR(order) prediction of y_{t+1} from y_0..y_t, for y (B, T, m); with
    u (B, T, k) and input_order q > 0 the ARX(order, q) prediction from y_0..y_t and u_0..u_t; offset: with
    a constant regressor; prior: the recursion's theta_0 and P_0 (feature_prior; a MixturePrior runs
    mop.filters.mixture.mixture_predict, on complete outputs); updates_from: the first
    y_s whose pair updates the fit (mop.filters.arx.arx_predict; default max(order, q)). Where y is missing
    (NaN) the recursion fills it with its own predictions held within the range of the outputs measured
    from row bounds_from on, widened by twice its span (arx_predict's bounded): a free run from an unstable
    fit stays finite (known_range (2, m): and within the range of outputs measured before the record,
    model.rls_fill_range). With u = None, q = 1 and no offset or prior it is the paper's matrix RLS
    (mop.filters.rls.rls_predict)."""
    pad = lambda a: torch.cat([a, a.new_zeros(a.shape[0], 1, a.shape[2])], dim=1).double()  # noqa: E731
    u_lags = pad(u) if input_order > 0 else None  # the pad rows are never read
    if isinstance(prior, MixturePrior):  # complete outputs, no offset (check_features)
        return mixture_predict(pad(y), u_lags, order, input_order, prior)[:, 1:].to(y.dtype)
    q = max(input_order, 1)
    r = arx_predict(pad(y), u_lags, order, q, offset, prior, updates_from, bounds_from, cubes, known_range)
    return r[:, 1:].to(y.dtype)  # (B, T, m)


def augment(
    inputs: Tensor, cfg: ModelConfig, fitted: Tensor | None = None
) -> tuple[Tensor, Tensor | None, Tensor | None]:
    """inputs (B, T, d_in) -> (network inputs (B, T, d_in + extra), scale s (B, T, 1)|None, base r|None).
    fitted (B, d, m) float64|None: each record's feature coefficients fitted on its own estimation record
    (train.context_prefix, mop.train.context), the inputs in that record's normalised units: the feature
    and moments then run as those of the model given the coefficients as a listed model.rls_prior with
    record_prior_steps = FITTED_PRIOR_STEPS (mop.incontext.fitted_to_context), one record each; without
    record_norm the feature runs as the records recipe's does on a record in its global units (a listed
    model.rls_prior, held at it with model.rls_fixed)."""
    m, k = cfg.output_dim, input_count(cfg)
    y, seen = observed_outputs(inputs, cfg)  # (B, T, m), NaN where missing
    u = inputs[..., m : m + k] if cfg.arx_order > 0 else None
    if cfg.record_norm == "causal":
        steps = cfg.record_prior_steps if fitted is None else FITTED_PRIOR_STEPS
        mask = None if seen is None else torch.cat([seen, torch.ones_like(inputs[..., m : m + k] > 0)], -1)
        mean, std = running_moments(inputs[..., : m + k], mask, steps)  # (B, T, m + k) each
        base = _framed_feature(y, u, mean, std, cfg, fitted) if cfg.rls_order > 0 else None
        if cfg.record_moments == "filled" and seen is not None:
            mean, std = filled_moments(inputs[..., : m + k], y, seen, base, steps)
        residual = None
        if cfg.residual_scale != "none":
            residual = residual_scale(y, base, seen, std[..., :m], cfg.residual_scale, cfg.residual_decay)
        return _record_assemble(inputs, mean, std, base, seen, m, residual)
    prior = feature_prior(cfg)
    if fitted is not None:  # the inputs are in the estimation record's units, where the coefficients hold
        prior = (fitted.double(), 0.0 if cfg.rls_fixed else PRIOR_P0)
    base = None
    if cfg.rls_order > 0:
        base = rls_next(y, cfg.rls_order, u, cfg.arx_order, cfg.rls_offset, prior, cubes=cfg.rls_cubes)
    scale = running_scale(inputs[..., :m]) if cfg.input_scale == "running" else None
    return _assemble(inputs, scale, base, m), scale, base


def filled_moments(
    z: Tensor, y: Tensor, seen: Tensor, base: Tensor, prior_steps: int = 0
) -> tuple[Tensor, Tensor]:
    """model.record_moments = "filled": running_moments of z (B, T, m + k) with each missing output y_t
    (t >= 1) replaced by the feature's prediction of it, base[:, t - 1] (a missing y_0 stays left out)."""
    m = y.shape[-1]
    predicted = torch.cat([y[:, :1], base[:, :-1].to(y)], dim=1)  # (B, T, m): the feature's y_t
    filled = torch.where(seen, y, predicted)
    mask = seen.clone()
    mask[:, 1:] = True
    full = torch.cat([filled, z[..., m:]], dim=-1)
    return running_moments(full, torch.cat([mask, torch.ones_like(z[..., m:] > 0)], dim=-1), prior_steps)


def feature_start(cfg: ModelConfig) -> int:
    """r = max(p, q): the RLS / ARX feature predicts the last value up to step r, then regresses."""
    return max(cfg.rls_order, cfg.arx_order)


def feature_frame(mean: Tensor, std: Tensor, cfg: ModelConfig) -> tuple[Tensor, Tensor]:
    """record_norm: the fixed frame (shift, scale) (B, m + k) the RLS / ARX feature runs in: each channel's
    mean and std over steps 0..r (feature_start; std 0 -> 1). Known at step r, before the first fit, so
    causal; a fixed affine map of each channel, so the feature (its ridge prior P_0 = I included) is
    equivariant to the record's units. With a listed model.rls_prior (coefficients fitted on one record in
    its normalised units: a fine-tuned class model) the frame is those units (shift 0, scale 1), where the
    coefficients hold."""
    if isinstance(cfg.rls_prior, list):
        return torch.zeros_like(mean), torch.ones_like(std)
    return mean, torch.where(std > 0, std, torch.ones_like(std))


def _framed_feature(
    y: Tensor, u: Tensor | None, mean: Tensor, std: Tensor, cfg: ModelConfig, fitted: Tensor | None = None
) -> Tensor:
    """The RLS / ARX feature (B, T, m) of y (B, T, m), u (B, T, k)|None run in feature_frame, in y's units.
    With a listed model.rls_prior, or each record's coefficients `fitted` (B, d, m), from the fitted start
    (fitted_start)."""
    m, r = cfg.output_dim, min(feature_start(cfg), y.shape[1] - 1)
    shift, scale = feature_frame(mean[:, r : r + 1], std[:, r : r + 1], cfg)  # (B, 1, m + k) each
    if fitted is not None:  # the coefficients' units are the inputs' (shift 0, scale 1), as a listed prior's
        shift, scale = torch.zeros_like(shift), torch.ones_like(scale)
    ys = (y.double() - shift[..., :m]) / scale[..., :m]
    us = None if u is None else (u.double() - shift[..., m:]) / scale[..., m:]
    if fitted is not None:
        rs = fitted_start(ys, us, cfg, (fitted.double(), 0.0 if cfg.rls_fixed else PRIOR_P0))
    elif starts_fitted(cfg):
        rs = fitted_start(ys, us, cfg)
    else:
        rs = rls_next(
            ys, cfg.rls_order, us, cfg.arx_order, cfg.rls_offset, feature_prior(cfg), cubes=cfg.rls_cubes
        )
    return (rs * scale[..., :m] + shift[..., :m]).to(y.dtype)


def first_values(y: Tensor) -> Tensor:
    """(B, 1, m): each channel's y_0 where it is measured, else 0 (in a fitted prior's frame, the estimation
    record's mean); known at step 0, so causal."""
    first = y[:, :1]
    return torch.where(torch.isnan(first), torch.zeros_like(first), first)


def starts_fitted(cfg: ModelConfig) -> bool:
    """Whether the RLS / ARX feature starts as fitted_start does: a class model (record_norm) whose
    model.rls_prior lists coefficients fitted on an estimation record (a fine-tune)."""
    return cfg.record_norm == "causal" and isinstance(cfg.rls_prior, list)


def fitted_start(ys: Tensor, us: Tensor | None, cfg: ModelConfig, prior: Prior | None = None) -> Tensor:
    """The feature r (B, T, m) of a class model with a listed model.rls_prior (coefficients fitted on an
    estimation record, in its normalised units ys (B, T, m), us (B, T, k)|None): the record read as if it
    had rested at its first values before step 0 (first_values; u_0), so the fitted ARX predicts from step 1
    on, y_1 from phi_0 = [y_0, y_0, ..., u_0, u_0, ..., 1], as mop.identify.arx's fitted ARX does (its lags
    before the record's start are its first values). Without it the recursion's start-up holds y_{t-1} for
    t <= r = max(p, q) and then regresses on zeros before step 0: a record simulated from its start (every
    y_t, t >= 1, missing) enters its free run from r held values (tank_records plant 3 from step 0: RMSE 0.76
    over its first 100 steps, against the fitted ARX's 0.26). The fit updates on the record's pairs only,
    those of the recursion without the pad (y_s, s >= r). prior: (theta_0 (d, m) or one per record
    (B, d, m), P_0) instead of the model's (feature_prior)."""
    r = feature_start(cfg)
    first_y = first_values(ys).expand(-1, r, -1)
    yp = torch.cat([first_y, ys], dim=1)
    up = None if us is None else torch.cat([us[:, :1].expand(-1, r, -1), us], dim=1)
    prior = feature_prior(cfg) if prior is None else prior
    # bounds_from=r: the r assumed values before the record are not measured, so they set no bounds
    rs = rls_next(
        yp,
        cfg.rls_order,
        up,
        cfg.arx_order,
        cfg.rls_offset,
        prior,
        updates_from=2 * r,
        bounds_from=r,
        cubes=cfg.rls_cubes,
        known_range=fill_range(cfg),
    )
    return rs[:, r:]


def fill_range(cfg: ModelConfig) -> Tensor | None:
    """model.rls_fill_range as (2, m) float64 (lows, highs), or None."""
    if cfg.rls_fill_range is None:
        return None
    return torch.tensor(cfg.rls_fill_range, dtype=torch.float64).reshape(2, cfg.output_dim)


def _record_assemble(
    inputs: Tensor,
    mean: Tensor,
    std: Tensor,
    base: Tensor | None,
    seen: Tensor | None,
    m: int,
    residual: Tensor | None = None,
) -> tuple[Tensor, Tensor, Tensor]:
    """record_norm: (network inputs [zn, any mask channels, rn (, log c / std)], the correction's scale
    (B, T, m): std_t(y), or the residual scale c_t where given, b (B, T, m)): zn the normalised [y, u]
    (B, T, m + k), 0 where an output is missing; rn the normalised RLS feature; b the feature, else the
    running mean of y."""
    d = mean.shape[-1]  # m + k
    zn = normalise(inputs[..., :d], mean, std)
    if seen is not None:
        zn = torch.cat([torch.where(seen, zn[..., :m], torch.zeros_like(zn[..., :m])), zn[..., m:]], dim=-1)
    mean_y, std_y = mean[..., :m], std[..., :m]
    parts = [zn, inputs[..., d:]]
    if base is not None:
        parts.append(normalise(base, mean_y, std_y))
    scale = std_y
    if residual is not None:
        defined = (std_y > 0) & (residual > 0)
        ratio = torch.where(defined, residual / torch.where(defined, std_y, torch.ones_like(std_y)), 1.0)
        parts.append(ratio.log().to(inputs.dtype))
        scale = residual
    b = mean_y if base is None else base.double()
    return torch.cat(parts, dim=-1), scale.to(inputs.dtype), b.to(inputs.dtype)


def residual_scale(
    y: Tensor, base: Tensor, seen: Tensor | None, std_y: Tensor, mode: str = "running", decay: float = 0.5
) -> Tensor:
    """c_t (B, T, m) float64 of model.residual_scale = mode (the module docstring) from the outputs y
    (B, T, m) (NaN where missing), the feature base (B, T, m) (base[:, t] predicts y_{t+1}), the mask seen
    (B, T, m) (None: all measured) and std_t(y) (B, T, m); decay: model.residual_decay.

    residual_update's recursion from v = n = 0, unrolled over the whole window at once: with k_t the count
    of measured outputs among y_1..y_t (y_0 has no prediction), v_t = sum over measured s <= t of
    (1 - decay) e_s^2 decay^(k_t - k_s) (e_s = y_s - base_{s-1}) and n_t = 1 - decay^(k_t), the sum taken
    by logcumsumexp so that decay^(-k_s) never overflows (the step-by-step loop cost ~85 us a position,
    most of a 2 x 64 class model's forward on 81 inputs). Equal to residual_update step by step to float64
    rounding (tests/test_residual_scale.py)."""
    y, base = y.double(), base.double()
    measured = torch.isfinite(y) if seen is None else seen & torch.isfinite(y)
    measured = torch.cat([torch.zeros_like(measured[:, :1]), measured[:, 1:]], dim=1)  # y_0: no update
    e2 = torch.cat([torch.zeros_like(y[:, :1]), (y[:, 1:] - base[:, :-1]) ** 2], dim=1)
    rate = -math.log(decay)  # decay^k = exp(-rate k)
    k = measured.double().cumsum(1)
    terms = torch.where(measured, ((1 - decay) * e2).log() + rate * k, torch.full_like(e2, -math.inf))
    v = (torch.logcumsumexp(terms, dim=1) - rate * k).exp()
    n = -torch.expm1(-rate * k)
    in_gaps = None if seen is None or mode != "measured" else seen
    return residual_from(v, n, std_y.double(), in_gaps)


def residual_update(
    v: Tensor, n: Tensor, y: Tensor, predicted: Tensor, seen: Tensor | None, lam: float = 0.5
) -> tuple[Tensor, Tensor]:
    """One step of the weighted error sums (B, m): v <- lam v + (1 - lam) e^2, n <- lam n + (1 - lam),
    e = y - predicted, where y is measured (seen None: all); unchanged elsewhere. lam: residual_decay."""
    measured = torch.isfinite(y) if seen is None else seen & torch.isfinite(y)
    e2 = torch.where(measured, (y - predicted) ** 2, torch.zeros_like(v))
    return torch.where(measured, lam * v + (1 - lam) * e2, v), torch.where(measured, lam * n + (1 - lam), n)


def residual_from(v: Tensor, n: Tensor, std_y: Tensor, seen: Tensor | None = None) -> Tensor:
    """c = sqrt(v / n + RESIDUAL_FLOOR std^2), with std^2 in place of v / n before any error (n = 0);
    seen (B, m) (model.residual_scale = "measured"): std itself where the output is missing."""
    mean_sq = torch.where(n > 0, v / torch.where(n > 0, n, torch.ones_like(n)), std_y**2)
    c = (mean_sq + RESIDUAL_FLOOR * std_y**2).sqrt()
    return c if seen is None else torch.where(seen, c, std_y)


def _assemble(inputs: Tensor, scale: Tensor | None, base: Tensor | None, m: int) -> Tensor:
    """[y / s, u, log s, r / s] (the parts that are on) along the last axis."""
    parts = [inputs]
    if scale is not None:
        parts = [inputs[..., :m] / scale, inputs[..., m:], scale.log()]
    if base is not None:
        parts.append(base if scale is None else base / scale)
    return parts[0] if len(parts) == 1 else torch.cat(parts, dim=-1)


def restore(
    mu: Tensor, var: Tensor | None, scale: Tensor | None, base: Tensor | None
) -> tuple[Tensor, Tensor | None]:
    """Network mean/variance (B, T, m) -> predictions in the data's units: s mu + r and s^2 var."""
    if scale is not None:
        mu = mu * scale
        var = None if var is None else var * scale**2
    if base is not None:
        mu = mu + base
    return mu, var


class FeatureState:
    """The features one input at a time (streaming): running sums and the RLS fit (theta, P) per system."""

    def __init__(self, cfg: ModelConfig, batch_size: int, device: torch.device, dtype: torch.dtype) -> None:
        self.cfg, self.m, self.t = cfg, cfg.output_dim, 0
        self.sum_sq = torch.zeros(batch_size, 1, device=device, dtype=dtype)
        p, q, self.k = cfg.rls_order, cfg.arx_order, input_count(cfg)
        d = regressor_count(cfg)
        if p > 0:
            f64 = dict(device=device, dtype=torch.float64)
            like = torch.zeros((), **f64)
            prior = feature_prior(cfg)
            if isinstance(prior, MixturePrior):  # the K recursions and their weights (mixture_predict)
                self.mixture = MixtureState(prior, batch_size, like)
            else:
                self.mixture = None
                self.theta, self.P = initial_state(prior, batch_size, d, self.m, like)  # as rls_loop
            self.recent = torch.zeros(batch_size, p + 1, self.m, **f64)
            self.recent_u = torch.zeros(batch_size, q + 1, self.k if q > 0 else 0, **f64)
        # with an observation mask the RLS feature skips pairs next to gaps (mop.filters.rls._rls_run_gaps):
        # once a gap has come, the stream recomputes it over the inputs so far (O(t) per step), exactly the
        # forward's; before, the one-step updates equal it (nothing missing)
        self.history = [] if cfg.observation_mask and p > 0 else None
        self.gapped = False
        if cfg.record_norm == "causal":
            self.stats = RecordStats(batch_size, self.m + self.k, device, cfg.record_prior_steps)
        if cfg.residual_scale != "none":  # the weighted error sums and the feature's last prediction
            f64 = dict(device=device, dtype=torch.float64)
            self.res_v, self.res_n = (torch.zeros(batch_size, self.m, **f64) for _ in range(2))
            self.predicted = None

    def step(self, z: Tensor) -> tuple[Tensor, Tensor | None, Tensor | None]:
        """z_t (B, d_in) -> network input (B, 1, d_in + extra), s_t (B, 1, 1)|None, r_{t+1} (B, 1, m)|None."""
        y, seen = observed_outputs(z, self.cfg)
        if self.history is not None:  # kept until the first gap; from there the forward's features
            self.history.append(z)
            self.gapped = self.gapped or not bool(seen.all())
            if self.gapped:
                self.t += 1
                net, scale, base = augment(torch.stack(self.history, dim=1), self.cfg)
                return net[:, -1:], *(None if a is None else a[:, -1:] for a in (scale, base))
        scale = base = None
        if self.cfg.input_scale == "running":
            self.sum_sq = self.sum_sq + (y**2).mean(-1, keepdim=True)
            scale = (self.sum_sq / (self.t + 1) + SCALE_EPS).sqrt()[:, None]  # (B, 1, 1)
        if self.cfg.record_norm == "causal":
            return self._record_step(z, seen)
        if self.cfg.rls_order > 0:
            u = z[:, self.m : self.m + self.k] if self.cfg.arx_order > 0 else z[:, :0]
            base = self._rls_step(y.double(), u.double()).to(z.dtype)[:, None]  # (B, 1, m)
        self.t += 1
        return _assemble(z[:, None], scale, base, self.m), scale, base

    def _record_step(self, z: Tensor, seen: Tensor | None) -> tuple[Tensor, Tensor, Tensor]:
        """step with record_norm: the running moments, and the RLS feature in its frame from step r on."""
        m, k, r = self.m, self.k, feature_start(self.cfg)
        mask = None if seen is None else torch.cat([seen, torch.ones_like(z[:, m : m + k] > 0)], -1)
        mean, std = self.stats.update(z[:, : m + k], mask)  # (B, m + k) each
        base = None
        if self.cfg.rls_order > 0:
            if self.t == r:  # the frame is fixed now; the buffers move into it
                self._enter_frame(*feature_frame(mean, std, self.cfg))
            zs = z[:, : m + k].double()
            zs = zs if self.t < r else (zs - self.shift) / self.scale
            rs = self._rls_step(zs[:, :m], zs[:, m : m + k] if self.cfg.arx_order > 0 else zs[:, :0])
            if self.t >= r:
                rs = rs * self.scale[:, :m] + self.shift[:, :m]
            base = rs.to(z.dtype)[:, None]  # (B, 1, m)
        residual = None
        if self.cfg.residual_scale != "none":
            if self.predicted is not None:
                y = z[:, :m].double()
                lam = self.cfg.residual_decay
                self.res_v, self.res_n = residual_update(self.res_v, self.res_n, y, self.predicted, seen, lam)
            # no gap has come (after one the forward's features are used), so "measured" is "running" here
            residual = residual_from(self.res_v, self.res_n, std[:, :m])[:, None]  # (B, 1, m)
            self.predicted = base[:, 0].double()
        self.t += 1
        rows = (z[:, None], mean[:, None], std[:, None], base, None if seen is None else seen[:, None])
        return _record_assemble(*rows, m, residual)

    def _enter_frame(self, shift: Tensor, scale: Tensor) -> None:
        """Fix the RLS feature's frame (B, m + k) and move the buffered past outputs and inputs into it."""
        m, q = self.m, self.recent_u.shape[-1]
        self.shift, self.scale = shift, scale
        self.recent = (self.recent - shift[:, None, :m]) / scale[:, None, :m]
        self.recent_u = (self.recent_u - shift[:, None, m : m + q]) / scale[:, None, m : m + q]

    def _rls_step(self, y: Tensor, u: Tensor) -> Tensor:
        """As rls_predict (arx_predict with q = arx_order > 0): fit the pair (phi_{t-1}, y_t) once t >= r =
        max(p, q), then predict y_{t+1} (y_t for t < r; by regression from the first values with a listed
        prior under record_norm: fitted_start); u (B, k) is u_t (B, 0 without input lags)."""
        p, q, t = self.cfg.rls_order, self.cfg.arx_order, self.t
        r = max(p, q)
        fitted = starts_fitted(self.cfg)
        if fitted and t == 0:  # fitted_start: the lags before step 0 are the first values
            self.recent = first_values(y[:, None]).expand_as(self.recent).clone()
            self.recent_u = u[:, None].expand_as(self.recent_u).clone()
        self.recent = torch.cat([self.recent[:, 1:], y[:, None]], dim=1)  # (B, p+1, m): y_{t-p}..y_t
        self.recent_u = torch.cat([self.recent_u[:, 1:], u[:, None]], dim=1)  # (B, q+1, k): u_{t-q}..u_t
        if t >= r and self.mixture is not None:
            self.mixture.update(self._phi(p, q, 0), y)
        elif t >= r:
            self.theta, self.P = rls_update(self.theta, self.P, self._phi(p, q, 0), y)
        if t < r and not fitted:
            return y
        if self.mixture is not None:
            return self.mixture.predict(self._phi(p, q, 1))
        return (self.theta.mT @ self._phi(p, q, 1)[..., None])[..., 0]

    def _phi(self, p: int, q: int, last: int) -> Tensor:
        """(B, p m + q k [+ 1]): [y_s; ...; y_{s-p+1}; u_s; ...; u_{s-q+1} (; 1 with rls_offset)] for
        s = t - 1 (last = 0) or t (1)."""
        parts = [regressors(self.recent[:, last : p + last], p)[:, -1]]
        if self.cfg.rls_cubes:
            parts.append(parts[0][:, : self.cfg.rls_cubes * self.m] ** 3)
        if q > 0:
            parts.append(regressors(self.recent_u[:, last : q + last], q)[:, -1])
        if self.cfg.rls_offset:
            parts.append(parts[0].new_ones(parts[0].shape[0], 1))
        return torch.cat(parts, dim=-1) if len(parts) > 1 else parts[0]
