"""The fine-tune's source: a run that starts from another model's weights (`mop train --data FILE --init
SOURCE`).

train.init names the source: a run directory or `pretrained:NAME`. Before any training, a source whose model
differs from the run's in any architecture key is refused (check_init: one line, naming the first); at step 0
the source's weights are loaded (load_init; a resumed run continues from its own checkpoint instead).
mop.recipe.training hands both to the training loop. The run's config.json keeps train.init, so the run says
where it started. The config layering (the source's model, its normalisation and the short schedule) is
mop.recipe.finetune's.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from torch import Tensor, nn

from mop.checkpoint import load_model_weights
from mop.config import ModelConfig, RunConfig
from mop.errors import MopError
from mop.pretrained import resolve_run_dir
from mop.runs import load_config, retrain_hint

# the feature's starting coefficients: data the run fits (model.rls_prior=fit), no weights of the network
PRIOR_KEYS = (
    "rls_prior",
    "rls_prior_cov",
    "rls_p0",
    "rls_prior_weights",
    "rls_prior_noise",
    "rls_fixed",
    "rls_fill_range",
)
# how the training loss weighs positions: a choice of the fine-tune, no part of the network
LOSS_KEYS = ("gap_loss", "horizon_loss")
# record_norm's start from the estimation record's moments: data the fine-tune knows, no weights
NORM_KEYS = ("record_prior_steps",)
# the in-context identifier's orders and intercept: the network reads its one-step prediction (output_dim
# numbers, mop.models.features.extra_input_dim) whatever its orders, so a fine-tune may identify the record
# with other orders (those `mop fit arx` picks, say) as long as the feature stays of the source's kind
ORDER_KEYS = ("rls_order", "arx_order", "rls_offset", "rls_cubes")
# how a trained model simulates past its measured outputs (mop.models.forecast): the outputs read as missing
# ("gap", a model with an observation mask) or its own predictions fed back ("rollout"); no weights
FORECAST_KEYS = ("forecast_mode",)


def check_init(config: RunConfig) -> None:
    """One-line MopError unless train.init's model has the run's architecture (every model key but the
    feature's prior, PRIOR_KEYS, the loss's weighting, LOSS_KEYS, the moments' start, NORM_KEYS, and the
    feature's orders, ORDER_KEYS, where the feature stays of the source's kind: RLS-AR or ARX, or none)."""
    if not config.train.init:
        return
    source = load_config(config.train.init).model
    free = PRIOR_KEYS + LOSS_KEYS + NORM_KEYS + FORECAST_KEYS
    if _feature_kind(source) == _feature_kind(config.model):
        free += ORDER_KEYS
    if drops_residual_scale(source, config.model):
        free += ("residual_scale", "residual_decay")
    for field in dataclasses.fields(source):
        if field.name in free:
            continue
        ours, theirs = getattr(config.model, field.name), getattr(source, field.name)
        if ours != theirs:
            raise MopError(
                f"--init {config.train.init}: its model has model.{field.name}={theirs!r}, this run "
                f"{ours!r}; fine-tuning keeps the source's architecture: drop the model.{field.name} "
                "override"
                " (or train from scratch without --init)"
            )


def _feature_kind(model: ModelConfig) -> str:
    """ "ARX", "AR" (output-only RLS) or "none": what the network's feature input means."""
    return "none" if model.rls_order == 0 else "ARX" if model.arx_order > 0 else "AR"


def drops_residual_scale(source: ModelConfig, model: ModelConfig) -> bool:
    """Whether a fine-tune of `source` into `model` drops the residual scale (model.residual_scale = "none"
    where the source's is "running" or "measured"; mop.models.features): its correction is then scaled by
    the record's running std_t(y), as record_norm's is without one, and the read-in loses the m channels of
    log(c_t / std_t(y)). The residual scale is the feature's recent one-step error; in a free run that feeds
    the model's own predictions back (model.forecast_mode = "rollout") that error is the correction itself
    and the scale fades, so a fine-tune that simulates by rollout may drop it. On the F-16 record this did
    not make pretrained:lti-siso's correction help (docs/results/benchmarks.md, F-16)."""
    return (
        source.record_norm == model.record_norm == "causal"
        and source.residual_scale != "none"
        and model.residual_scale == "none"
    )


def load_init(config: RunConfig, model: nn.Module) -> None:
    """Copy train.init's weights into `model` (in place, so an optimizer built on it keeps its params); where
    the run drops the source's residual scale (drops_residual_scale) the read-in's last output_dim input
    columns, those of log(c_t / std_t(y)) (mop.models.features._record_assemble), are left out."""
    run_dir = Path(resolve_run_dir(config.train.init))
    source = load_config(config.train.init).model
    adapt = None
    if drops_residual_scale(source, config.model):
        m = source.output_dim

        def adapt(tensors: dict[str, Tensor]) -> dict[str, Tensor]:
            return {**tensors, "read_in.weight": tensors["read_in.weight"][:, :-m].contiguous()}

    load_model_weights(run_dir / "model.safetensors", model, retrain=retrain_hint(run_dir), adapt=adapt)
