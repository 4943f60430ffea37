"""The official protocol on one test record, the published baselines, and the plots a control engineer reads.

Protocol: a predictor fitted on the estimation part receives the test's input and its first n measured
outputs (n = Record.init_window), simulates y_n.. from the input alone (mop.records.simulate_all), and is
scored by RMSE = sqrt(mean_t (y_t - ysim_t)^2) over t >= n, in the output's units, averaged over the output
channels' squares. A simulation that diverges (mop.records.divergence_step) scores inf, with its step.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from mop.plots import plt, save
from mop.record import Record
from mop.records import simulate_all, simulation_rmse

CITATION = (
    'Champneys, Beintema, Toth, Schoukens, Rogers, "Baseline Results for Selected Nonlinear System '
    'Identification Benchmarks", IFAC-PapersOnLine 58(15), 2024 (result files of MDCHAMP/nonlinear_baselines)'
)
# Published simulation RMSE on the official tests, in the output's units (V for Silverbox, read from the mV
# of the paper's tables): {benchmark: {test: {model: rmse}}}
PUBLISHED: dict[str, dict[str, dict[str, float]]] = {
    "silverbox": {
        "test_multisine": {"FIR-MLP": 18.9e-3, "RNN": 1.6e-3, "LSTM": 1.5e-3, "GRU": 1.5e-3},
        "test_arrow_full": {
            "FIR-MLP": 20.2e-3, "RNN": 4.9e-3, "LSTM": 2.7e-3, "GRU": 2.8e-3, "OLSTM": 2.4e-3,
        },
        "test_arrow_no_extrapolation": {"FIR-MLP": 15.3e-3, "RNN": 1.7e-3, "LSTM": 1.0e-3, "GRU": 0.9e-3},
    },
    "wiener-hammerstein": {
        "test": {"FIR-MLP": 24.8e-3, "RNN": 6.9e-3, "LSTM": 4.4e-3, "GRU": 4.0e-3},
    },
    "cascaded-tanks": {
        "test": {
            "ARX": 0.685, "polynomial NARX": 0.413, "GP-NARX": 0.622, "MLP-NARX": 2.04, "FIR-MLP": 1.43,
            "RNN": 0.543, "LSTM": 0.490, "GRU": 0.396,
        },
    },
    "ced": {
        "test low amplitude": {"ARX": 0.292, "polynomial NARX": 0.100, "GP-NARX": 0.102, "RNN": 0.096},
        "test high amplitude": {"ARX": 0.331, "polynomial NARX": 0.141, "GP-NARX": 0.090, "RNN": 0.235},
    },
}  # fmt: skip


@dataclasses.dataclass(frozen=True)
class TestScore:
    """One predictor on one test record: the simulation RMSE of y[n:], and the step it diverged at."""

    rmse: float  # inf where diverged
    diverged_at: int | None  # the time step t of the test record, or None
    simulation: np.ndarray  # (T - n, m): ysim_n..ysim_{T-1}


def run_test(predictor, test: Record) -> TestScore:
    """The protocol on one test record (see the module docstring)."""
    (sim,) = simulate_all(predictor, [test.pair], max(test.init_window, 1))
    return score_test(test, sim)


def score_test(test: Record, sim: np.ndarray) -> TestScore:
    """The protocol's score of a simulation sim (T - n, m) of the test record after its first n outputs."""
    rmse, step = simulation_rmse(test.y, sim)
    return TestScore(rmse, None if step is None else max(test.init_window, 1) + step, sim)


def test_figure(
    test: Record, sims: dict[str, np.ndarray], units: str, out_dir: Path, stem: str
) -> list[Path]:
    """Three panels, first output channel: simulated against measured output over the test; the error over
    time; the error's RMS against the measured output's amplitude (bins of |y|: where extrapolation shows)."""
    n = max(test.init_window, 1)
    y = test.y[n:, 0]
    t = np.arange(n, len(test)) * (test.sampling_time or 1.0)
    fig, axes = plt.subplots(3, 1, figsize=(9, 9))
    axes[0].plot(t, y, color="black", lw=0.6, label="measured")
    for name, sim in sims.items():
        finite = np.isfinite(sim[:, 0])
        axes[0].plot(t[finite], sim[finite, 0], lw=0.5, label=name)
        axes[1].plot(t[finite], (y - sim[:, 0])[finite], lw=0.5, label=name)
        edges = np.quantile(np.abs(y), np.linspace(0, 1, 11))
        which = np.clip(np.digitize(np.abs(y), edges[1:-1]), 0, 9)
        rms = [np.sqrt(np.nanmean((y - sim[:, 0])[which == b] ** 2)) for b in range(10)]
        axes[2].plot(0.5 * (edges[1:] + edges[:-1]), rms, marker="o", label=name)
    axes[0].set_ylabel(f"y [{units}]")
    axes[1].set_ylabel(f"error [{units}]")
    axes[2].set_xlabel(f"|measured output| [{units}] (deciles)")
    axes[2].set_ylabel(f"RMS error [{units}]")
    axes[1].set_xlabel("time [s]" if test.sampling_time else "step")
    axes[2].set_yscale("log")
    for ax in axes:
        ax.legend(fontsize=7)
    axes[0].set_title(f"{stem}: free-run simulation after {n} measured outputs")
    return save(fig, out_dir, stem)
