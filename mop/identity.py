"""The identity of a run: the config keys its config.json holds, and so its hash (the name of its run
directory under `mop reproduce`), the check that a run directory holds this config, and the look-up of a
shipped pretrained model.

A key that config.json held when this rule came in is always written (FROZEN, FROZEN_SYSTEM: a record, not
to be edited), so every run directory and shipped model made before keeps its identity. Any other key, in
any section (system, model, train, data), is written only where it differs from its default: a knob added
later with a default leaves every existing identity unchanged, and a run that sets it gets a new one.
"""

from __future__ import annotations

import dataclasses
from typing import Any

_SYSTEM = ("family", "max_abs")
_LINEAR = (*_SYSTEM, "state_dim", "output_dim", "noise_var_w", "noise_var_v", "spectral_radius", "x0_std")
_SISO = (*_SYSTEM, "max_order", "mag_low", "mag_high", "phase_high", "noise_std")
_RLC = ("resistance", "inductance", "capacitance")

# section -> the keys always written (of the system section: per family; a family not named here writes
# only its family and the knobs away from their defaults)
FROZEN: dict[str, tuple[str, ...]] = {
    "model": (
        *("arch", "num_layers", "num_heads", "width", "context", "input_dim", "output_dim", "readout"),
        *("dropout", "position"),
    ),
    "train": (
        *("steps", "batch_size", "lr", "weight_decay", "grad_clip", "lr_schedule", "warmup_steps"),
        *("num_source_systems", "horizon", "seed", "device", "precision", "compile", "log_every"),
        *("checkpoint_every", "deterministic"),
    ),
    "data": ("path", "validation_fraction", "split_seed", "y_mean", "y_std", "u_mean", "u_std"),
}
FROZEN_SYSTEM: dict[str, tuple[str, ...]] = {
    "linear": _LINEAR,
    "upper-triangular": _LINEAR,
    "colored-noise": (*_LINEAR, "color_window"),
    "switching": (*_LINEAR, "switch_time"),
    "linear-inputs": (*_LINEAR, "input_dim", "input_std", "input_gain"),
    "quadrotor": (*_SYSTEM, "noise_var_w", "noise_var_v", "x0_std"),
    "lti-siso": _SISO,
    "wiener-hammerstein": (*_SISO, "skip"),
    # the plug-in families of examples/ (pendulum.py, rlc_circuit.py)
    "pendulum": (*_SYSTEM, "noise_var_w", "noise_var_v", "x0_std"),
    "rlc-circuit": (
        *_SYSTEM,
        *(f"{name}_{end}" for name in _RLC for end in ("min", "max")),
        *("dt", "input_std", "disturbance_std", "output_std", "initial_voltage_std", "output"),
    ),
}


def defaults(cls: type) -> dict[str, Any]:
    """{field: its default} of dataclass `cls` (fields without a default left out)."""
    out = {}
    for field in dataclasses.fields(cls):
        if field.default is not dataclasses.MISSING:
            out[field.name] = field.default
        elif field.default_factory is not dataclasses.MISSING:
            out[field.name] = field.default_factory()
    return out


def always_written(section: str, config: Any) -> tuple[str, ...]:
    """The keys of `section` (its dataclass `config`) written whatever their value."""
    if section == "system":
        return FROZEN_SYSTEM.get(config.family, ("family",))
    return FROZEN.get(section, ())


def identity(config: Any) -> dict[str, Any]:
    """The dict of a config with sections (a RunConfig): dataclasses.asdict(config), less a section that is
    None and, within each section, the keys neither always written nor away from their defaults."""
    data = {}
    for field in dataclasses.fields(config):
        section = getattr(config, field.name)
        if section is None:
            continue
        keep, default = always_written(field.name, section), defaults(type(section))
        data[field.name] = {
            key: value
            for key, value in dataclasses.asdict(section).items()
            if key in keep or key not in default or value != default[key]
        }
    return data
