"""A test record simulated with an estimation record as the model's in-context data (mop predict --context).

simulate_with_context(predictor, test, init, context) -> (T - init, m): ysim_init..ysim_{T-1} of the test
record, from its first `init` measured outputs and its inputs, after the model has read the context record:
one trajectory, the context's last part followed by the test, simulated from the test's step `init` (exactly
the by-hand concatenation of that part and the test, `mop predict --simulate L + init` on it).

Which part of the context: a learned model that reads at most C inputs (its trained context) gets the last
C - init steps of the context, so that its first window holds them and the test's init window; a predictor
without a limit gets all of it. With several context records the last one is read (the most recent).

The seam: at the join the record jumps from the context's last state to the test's first. Whether reading
across it helps is measured on the context record itself before the test is touched: its last H steps
(H = min(len / 4, 2000)) are simulated from their first `init` outputs, once alone and once after the part
of the context before them (the same seam, one record earlier); the context is used on the test only where
it simulated that held-out end at least as well (`choose=True`, the default), so it is never worse than no
context on that evidence. The choice is returned beside the simulation.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from mop.errors import MopError
from mop.record import Record
from mop.records import simulate_all, simulation_rmse


@dataclasses.dataclass(frozen=True)
class InContext:
    """A simulation of the test record and how the context was used."""

    simulation: np.ndarray  # (T - init, m)
    context_steps: int  # steps of the context read before the test (0: none)
    held_out_rmse: tuple[float, float] | None  # the context's held-out end: (alone, after its context)


def context_limit(predictor) -> int | None:
    """How many inputs the predictor reads at most (a context-limited learned model's C), else None."""
    model = getattr(predictor, "model", None)
    if model is not None and getattr(model, "context_limited", False):
        return int(model.cfg.context)
    return None


def check_context(test: Record, context: Sequence[Record]) -> None:
    """One-line MopError where the context does not fit the test record: no context, other widths, another
    sampling time (where both are known)."""
    if not context:
        raise MopError("--context: the file holds no record")
    for r in context:
        if (r.num_outputs, r.num_inputs) != (test.num_outputs, test.num_inputs):
            raise MopError(
                f"--context record {r.name!r} has {r.num_outputs} outputs and {r.num_inputs} inputs, the "
                f"test record {test.num_outputs} and {test.num_inputs}; give the same plant's channels"
            )
        if r.sampling_time and test.sampling_time and not np.isclose(r.sampling_time, test.sampling_time):
            raise MopError(
                f"--context record {r.name!r} is sampled every {r.sampling_time:g} s, the test every "
                f"{test.sampling_time:g} s; resample one of them"
            )
        if np.isnan(r.y).any():
            raise MopError(
                f"--context record {r.name!r} has missing outputs; give a complete record as context"
            )


def _joined(first: Record, second: Record) -> Record:
    u = None if first.u is None else np.concatenate([first.u, second.u])
    return Record(y=np.concatenate([first.y, second.y]), u=u, name=second.name)


def _simulate(predictor, record: Record, start: int) -> np.ndarray:
    return simulate_all(predictor, [record.pair], start)[0]


def _rmse(y: np.ndarray, sim: np.ndarray) -> float:
    return simulation_rmse(y, sim)[0]


def simulate_with_context(
    predictor, test: Record, init: int, context: Sequence[Record], choose: bool = True
) -> InContext:
    """The test record simulated after the context (see the module docstring)."""
    check_context(test, context)
    if not 1 <= init < len(test):
        raise MopError(f"the test's initialization window {init} must be in [1, {len(test) - 1}]")
    source = context[-1]
    limit = context_limit(predictor)
    keep = len(source) if limit is None else max(limit - init, 0)
    tail = source[len(source) - min(keep, len(source)) :]
    held = None
    if choose and len(tail) > 0:
        h = min(len(source) // 4, 2000)
        if h > init + 1:
            end, before = source[len(source) - h :], source[: len(source) - h]
            before = before[len(before) - min(keep, len(before)) :]
            alone = _rmse(end.y, _simulate(predictor, end, init))
            after = _rmse(end.y, _simulate(predictor, _joined(before, end), len(before) + init))
            held = (alone, after)
            if after > alone:
                tail = tail[:0]
    if len(tail) == 0:
        return InContext(_simulate(predictor, test, init), 0, held)
    return InContext(_simulate(predictor, _joined(tail, test), len(tail) + init), len(tail), held)
