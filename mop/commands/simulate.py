"""`mop simulate FAMILY`: simulate trajectories of a system family and save them to an .npz file.

The file holds y (B, T+1, m), u (B, T+1, k) for families with inputs, x (B, T+1, n), and every system
parameter as param_<name> (e.g. param_A, param_C, param_Q, param_R), as Trajectories.to_numpy_dict gives them.
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from mop.atomic import atomic_path
from mop.commands import OverridesAnywhere
from mop.config import SystemConfig, apply_overrides, to_dict
from mop.errors import MopError
from mop.memory import check_allocation
from mop.systems import FAMILIES, generator, make_family

EXAMPLES = """
examples:
  mop simulate linear --systems 1000 --horizon 50 --seed 0 --out linear.npz
  mop simulate switching --horizon 100 switch_time=50 --out switching.npz
  mop simulate linear noise_var_w=0.1 noise_var_v=0.1 --out noisy.npz
  python -c "import numpy as np; d = np.load('linear.npz'); print({k: v.shape for k, v in d.items()})"
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.__class__ = OverridesAnywhere  # the subparser the dispatcher made for us
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    knobs = [
        f"  {name}: "
        + " ".join(f"{k}={v}" for k, v in to_dict(SystemConfig(family=name)).items() if k != "family")
        for name in FAMILIES.names()
    ]
    parser.epilog = "overrides (key=value) per family, with their defaults:\n" + "\n".join(knobs) + EXAMPLES
    parser.add_argument("family", choices=FAMILIES.names(), help="system family to sample from")
    parser.add_argument("overrides", nargs="*", metavar="key=value", help="the family's settings (see below)")
    parser.add_argument(
        "--systems", type=int, default=1000, help="number of systems, one trajectory each (1000)"
    )
    parser.add_argument(
        "--horizon", type=int, default=50, help="steps T; each trajectory holds y_0..y_T (50)"
    )
    parser.add_argument(
        "--seed", type=int, default=0, help="random seed; the same seed gives the same file (0)"
    )
    parser.add_argument("--out", required=True, help="output .npz file (written atomically)")
    parser.add_argument(
        "--dtype", choices=("float32", "float64"), default="float32", help="array dtype (float32)"
    )
    parser.add_argument("--device", default="cpu", help="torch device to simulate on (cpu)")


SIMULATE_FACTOR = 3  # peak memory / (x, y, u arrays): 2.7 (linear) and 3.2 (quadrotor) measured, B=T=2000


def check_simulation_memory(family, systems: int, horizon: int, itemsize: int) -> None:
    """Refuse (one line, with the number) a simulation whose states, outputs and inputs would not fit."""
    values = family.state_dim + family.output_dim + family.input_dim
    nbytes = SIMULATE_FACTOR * systems * (horizon + 1) * values * itemsize
    check_allocation(
        nbytes,
        f"simulating {systems} systems x {horizon + 1} steps x {values} values",
        "simulate fewer systems (--systems) or a shorter --horizon, in several files if need be",
    )


def run(args: argparse.Namespace) -> int:
    if args.systems < 1 or args.horizon < 1:
        raise MopError(f"--systems and --horizon must be >= 1, got {args.systems} and {args.horizon}")
    if not args.out.endswith(".npz"):
        raise MopError(f"--out must name an .npz file, got {args.out!r}")
    config = apply_overrides(SystemConfig(family=args.family), args.overrides)
    try:
        gen = generator(args.seed, args.device)
    except RuntimeError as err:
        raise MopError(f"cannot use device {args.device!r}: {err}") from None
    family = make_family(config, getattr(torch, args.dtype))
    check_simulation_memory(family, args.systems, args.horizon, getattr(torch, args.dtype).itemsize)
    traj = family.generate(args.systems, args.horizon, generator=gen)
    with atomic_path(args.out) as tmp:
        with open(tmp, "wb") as handle:
            np.savez(handle, **traj.to_numpy_dict())
    print(f"wrote {args.systems} {args.family} systems, y {tuple(traj.y.shape)}, to {args.out}")
    return 0
