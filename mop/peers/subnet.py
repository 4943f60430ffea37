"""deepSI's SUBNET with the library's defaults, as a peer under mop's protocol.

SUBNET (Beintema, Toth, Schoukens 2021, 2023) is the state-space model of the field's black-box state of the
art: an encoder estimates the state from the last nb inputs and na outputs before a subsection, then
x_{t+1} = f(x_t, u_t), y_t = h(x_t) simulate the subsection from its inputs alone, and the loss is that
free-run error (T = 50 steps). `deepSI.SUBNET(nu, ny, norm)` with every default (nx = 10, residual MLPs of
2 x 64 tanh) but the encoder's window, and `deepSI.fit` with its defaults (Adam, batch 256, T = 50): the
weights kept are those of the lowest simulation error on the validation record, here the estimation
record's last 20% (deepSI needs one; the first 80% trains), checked every VAL_FREQ iterations.

On purpose, two choices are mop's:
- na = nb = min(20, n): deepSI's default window of 20, fewer where the tests give fewer measured outputs (n
  = 5 on the cascaded tanks), so the encoder reads only the outputs the protocol measures;
- the iterations: those `--budget MINUTES` buys at REFERENCE_SECONDS a batch (measured on the 2-core CPU
  here, beside another job: 0.43 s), so the same budget trains the same steps on every machine, as mop's
  records recipe plans its own (the library's example trains a fixed count).
deepSI writes its checkpoints under ~/.deepSI-checkpoints (its own choice, kept).

An optional extra: `pip install "mop[benchmarks]"` (deepSI reads the official loader's data class) and `pip
install --no-deps deepsi==0.4.4 cloudpickle` (0.4.4 pins nonlinear_benchmarks < 0.2, whose data class 1.0
kept; its tests here check it runs).
"""

from __future__ import annotations

import contextlib
import importlib
import io
import math

import numpy as np
import torch
from torch import Tensor

from mop.errors import MopError
from mop.peers.runs import free_runs
from mop.record import Record
from mop.systems.base import Trajectories

INSTALL = 'pip install "mop[benchmarks]" && pip install --no-deps deepsi==0.4.4 cloudpickle'
WINDOW = 20  # deepSI's default na = nb
REFERENCE_SECONDS = 0.43  # one batch of 256 x 50 steps on the reference 2-core CPU (see the docstring)
VAL_FREQ = 100  # iterations between the validation simulations that choose the weights kept
VALIDATION_SHARE = 0.2


def deepsi():
    """The deepSI module; a one-line MopError naming the install command where it (or its loader) is
    missing."""
    try:
        return importlib.import_module("deepSI")
    except ImportError:
        raise MopError(f"the subnet peer is deepSI's SUBNET, which is not installed: {INSTALL}") from None


def iterations(minutes: float) -> int:
    """The training batches `minutes` buy at REFERENCE_SECONDS each (at least one)."""
    return max(1, int(math.floor(60 * minutes / REFERENCE_SECONDS)))


class SubnetPredictor:
    """A fitted SUBNET as a mop Predictor: simulate(traj, context) in the data's units (traj's y (B, T+1,
    m), u (B, T+1, k)), its state encoded from the last `window` measured steps before the context's end."""

    name = "subnet"

    def __init__(self, model, window: int, output_dim: int, iterations: int) -> None:
        self.model, self.window = model, window
        self.output_dim, self.iterations = output_dim, iterations

    def simulate(self, traj: Trajectories, context: int) -> Tensor:
        """(B, T+1-c, m): y_c..y_T from y_{c-w}..y_{c-1}, u_{c-w}.. (w = window) and the inputs."""
        w, data = self.window, deepsi().Input_output_data

        def run(y: np.ndarray, u: np.ndarray) -> np.ndarray:
            with torch.no_grad():
                sim = self.model.simulate(data(u=u, y=y, state_initialization_window_length=w))
            return np.asarray(sim.y, dtype=float)[w:].reshape(-1, y.shape[1])

        return free_runs(traj, context, w, self.name, "encodes its state", run)


def fit_subnet(
    records: list[Record], init_window: int, seed: int = 0, minutes: float = 5.0
) -> SubnetPredictor:
    """deepSI's SUBNET with its defaults (the module docstring), trained on the estimation records: the first
    80% of each trains, the last 20% validates; seeded by torch.manual_seed(seed) (deepSI's batches draw from
    their own fixed seed), iterations(minutes) batches. Its progress output is kept off the terminal."""
    dsi = deepsi()
    if any(r.u is None for r in records):
        raise MopError("the subnet peer (SUBNET) simulates from inputs: give records with inputs")
    if any(not (np.isfinite(r.y).all() and np.isfinite(r.u).all()) for r in records):
        raise MopError("the subnet peer (SUBNET) needs complete records: fill the missing samples first")
    w = max(1, min(WINDOW, init_window))
    train, val = [], []
    for r in records:
        cut = len(r.y) - math.ceil(VALIDATION_SHARE * len(r.y))
        train.append(dsi.Input_output_data(u=np.asarray(r.u, float), y=np.asarray(r.y, float))[:cut])
        val.append(dsi.Input_output_data(u=np.asarray(r.u, float), y=np.asarray(r.y, float))[cut - w :])
    nu, ny, norm = dsi.get_nu_ny_and_auto_norm(train)
    torch.manual_seed(seed)
    model = dsi.SUBNET(nu, ny, norm, na=w, nb=w)
    windows = sum(max(0, len(t) - w - 50 + 1) for t in train)
    if windows < 1:
        raise MopError(f"the subnet peer needs estimation records of more than {w + 50} steps")
    steps = iterations(minutes)
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        dsi.fit(
            model, train, val, n_its=steps, T=50, batch_size=min(256, windows), val_freq=min(VAL_FREQ, steps)
        )
    return SubnetPredictor(model.eval(), w, records[0].y.shape[1], steps)


def subnet_line(predictor: SubnetPredictor) -> str:
    """One line on what was trained."""
    return (
        f"deepSI SUBNET, its defaults (nx = 10, 2 x 64 residual MLPs, T = 50, batch 256), encoder window "
        f"{predictor.window}, {predictor.iterations} batches, the weights of the lowest validation simulation"
    )
