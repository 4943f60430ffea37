"""Training with an estimation record as context (train.context_prefix = N > 0): the class model learns on
the records it is used on in context.

In context (mop.incontext, the "fit" readings) a class model reads a test record after its feature's
coefficients were fitted by least squares on a separate estimation record, both in the estimation record's
normalised units (its per-channel mean and std). A class model trained without a prefix learns on windows
whose feature identifies the system from the window's own first steps (model.rls_p0: least squares from
step 0), so its correction learns to correct an ARX fitted on tens to hundreds of steps, not on a long
record.

With a prefix every training trajectory is N + T + 1 steps of one system: its first N steps are the
estimation record (prefix_fit: their mean and std, and the least-squares coefficients of the model's
feature over them, mop.filters.arx.least_squares_coefficients one trajectory each), the last T + 1 the
record the network reads, normalised by the prefix's moments. The network attends to those T + 1 steps only,
and its feature starts from each trajectory's coefficients as a listed model.rls_prior does
(mop.models.features.augment's `fitted`): so each training window is exactly a window of the "fit gain 1"
reading, the estimation record being the prefix. The loss is over those T steps, as without a prefix
(train.simulate_after: the free run starts at step s of the window, s >= c).
"""

from __future__ import annotations

import torch
from torch import Tensor

from mop.config import ModelConfig, RunConfig
from mop.errors import MopError, check_int
from mop.filters.arx import arx_regressors
from mop.models.features import input_count, regressor_count

LEAST_SQUARES_RIDGE = 1e-6  # least_squares_coefficients' ridge, times the pairs


def check_context_prefix(config: RunConfig) -> None:
    """One-line MopError where train.context_prefix cannot serve the run: it needs a simulated family, a
    feature that is an ARX / NARX (rls_order > 0, no coefficients of its own), the outputs as targets, and
    more steps than the feature's regressors. With model.record_norm = "causal" the network reads the window
    as a class model reads a test in context; without it, as the records recipe's network reads a record
    in its global units (the estimation record's moments), the feature starting from the fit (P_0 of a
    listed prior): the pretraining of a records start (mop.recipe.finetune.records_start)."""
    n, model = config.train.context_prefix, config.model
    check_int("train.context_prefix", n, 0)
    if n == 0:
        return
    if config.data is not None:
        raise MopError(
            "train.context_prefix draws each training system's estimation record before its window; a "
            "recorded file has its own: train on it without the prefix"
        )
    if config.train.target != "outputs":
        raise MopError(
            "train.context_prefix trains against each window's outputs in its estimation record's units; "
            "use train.target=outputs"
        )
    if model.rls_order == 0:  # no feature: the prefix gives the window's units alone
        return
    if model.rls_prior != "none":
        raise MopError(
            "train.context_prefix starts the feature from coefficients fitted on each system's estimation "
            "record: it needs no model.rls_prior (or no feature: model.rls_order=0)"
        )
    needed = max(model.rls_order, model.arx_order) + regressor_count(model)
    if n <= needed:
        raise MopError(
            f"train.context_prefix={n} steps cannot fit the feature's {regressor_count(model)} coefficients "
            f"an output by least squares: give more than {needed}"
        )


def prefix_fit(z: Tensor, prefix: int, model: ModelConfig) -> tuple[Tensor, Tensor | None]:
    """z (B, N + L, m + k) [y_t, u_t] of B systems, N = prefix -> (the last L steps (B, L, m + k) in the
    prefix's normalised units, float64; theta (B, d, m) float64, the feature's least-squares coefficients
    over the prefix in those units, None for a model without a feature: model.rls_order = 0). Each
    channel's units: its mean and std over the prefix (std 0 -> 1), as
    mop.incontext.context_normalization's (and the records recipe's record normalisation); theta as
    least_squares_coefficients on the prefix alone."""
    z = z.double()
    head = z[:, :prefix]
    mean, std = head.mean(1, keepdim=True), head.std(1, unbiased=False, keepdim=True)
    zn = (z - mean) / torch.where(std > 0, std, torch.ones_like(std))
    if model.rls_order == 0:
        return zn[:, prefix:], None
    m, q = model.output_dim, model.arx_order
    k = input_count(model)
    est = zn[:, :prefix]
    u = est[..., m : m + k] if q > 0 else None
    phi = arx_regressors(est[..., :m], u, model.rls_order, max(q, 1), model.rls_offset, model.rls_cubes)
    r = max(model.rls_order, q)
    rows, targets = phi[:, r - 1 : -1], est[:, r:, :m]  # the pairs (phi_{s-1}, y_s), s >= r
    d = rows.shape[-1]
    eye = torch.eye(d, dtype=rows.dtype, device=rows.device)
    gram = rows.transpose(1, 2) @ rows + LEAST_SQUARES_RIDGE * rows.shape[1] * eye
    theta = torch.linalg.solve(gram, rows.transpose(1, 2) @ targets)  # (B, d, m)
    return zn[:, prefix:], theta
