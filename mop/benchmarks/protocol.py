"""The official protocol on one test record, the published baselines, and the plots a control engineer reads.

Protocol: a predictor fitted on the estimation part receives the test's input and its first n measured
outputs (n = Record.init_window), simulates y_n.. from the input alone (mop.records.simulate_all), and is
scored by RMSE = sqrt(mean_t (y_t - ysim_t)^2) over t >= n, in the output's units, averaged over the output
channels' squares. A simulation that diverges (mop.records.divergence_step) scores inf, with its step.
"""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path

import numpy as np

from mop.plots import plt, save
from mop.record import Record
from mop.records import simulate_all, simulation_rmse

# A records run's candidates its held-out check did not keep, scored on the tests beside what it keeps
# (`mop benchmark`: results under "mop:network", "mop:feature"), as the results pages label them
NETWORK, FEATURE = "network", "feature"
ALONE = {NETWORK: "the network alone", FEATURE: "its least-squares feature alone"}

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

# The best black-box results published on each test (simulation RMSE in the output's units), as read in the
# authors' own code and paper sources; every one is trained on its simulation error.
# {benchmark: {test: (rmse, "method, paper")}}
STATE_OF_THE_ART: dict[str, dict[str, tuple[float, str]]] = {
    "silverbox": {
        "test_multisine": (0.26e-3, "SUBNET nx = 8 (Beintema, Toth, Schoukens, L4DC 2021)"),
        "test_arrow_full": (1.41e-3, "SUBNET nx = 4 (Beintema, Toth, Schoukens, L4DC 2021)"),
        "test_arrow_no_extrapolation": (0.307e-3, "SUBNET nx = 8 (Beintema, Toth, Schoukens, L4DC 2021)"),
    },
    "wiener-hammerstein": {"test": (0.241e-3, "SUBNET (Beintema, Toth, Schoukens, L4DC 2021)")},
    "cascaded-tanks": {
        "test": (0.30, "continuous-time SUBNET, median of 17 seeds (Beintema, Schoukens, Toth, ICLR 2023)"),
    },
    "emps": {"test": (2.64e-3, "dynoNet (Forgione and Piga 2021)")},
    "f16": {
        "F16Data_FullMSine_Level6_Validation": (
            0.180, "deep LRU, 6 layers, trained on every estimation record (Forgione, Mejari, Piga, CDC 2024)"
        ),
    },
    "f16-3": {  # the three accelerations pooled: sqrt of the mean of 0.180^2, 0.167^2, 0.368^2
        "F16Data_FullMSine_Level6_Validation": (
            0.255, "deep LRU, 6 layers (Forgione, Mejari, Piga, CDC 2024)"
        ),
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
    test: Record, sims: dict[str, np.ndarray], units: str, out_dir: Path, stem: str, scale: float = 1.0
) -> list[Path]:
    """Three panels, first output channel: simulated against measured output over the test; the error over
    time; the error's RMS against the measured output's amplitude (bins of |y|: where extrapolation shows).

    sims[name] is (T - n, m), ysim_n..; units "" leaves the unit brackets out; values are multiplied by
    `scale` (1e3 for mV of V). A simulation that diverged (mop.records.divergence_step) is drawn up to its
    divergence and marked with an x where it left; the axes stay on the measured output's range, so one
    diverged run does not flatten the others. The legend gives each simulation's RMSE."""
    n = max(test.init_window, 1)
    y = test.y[n:, 0] * scale
    t = np.arange(n, len(test)) * (test.sampling_time or 1.0)
    unit = f" [{units}]" if units else ""
    fig, axes = plt.subplots(3, 1, figsize=(9, 9))
    axes[0].plot(t, y, color="black", lw=0.6, label="measured")
    span = float(np.nanmax(y) - np.nanmin(y)) or 1.0
    low, high = float(np.nanmin(y)) - 0.25 * span, float(np.nanmax(y)) + 0.25 * span
    worst = 0.0
    edges = np.nanquantile(np.abs(y), np.linspace(0, 1, 11))  # deciles of |y|, the third panel's bins
    for name, sim in sims.items():
        rmse, step = simulation_rmse(test.y, sim)
        ys = sim[:, 0] * scale
        end = len(ys) if step is None else step
        err = y[:end] - ys[:end]
        shown = "diverged" if step is not None else f"{rmse * scale:.4g}" + (f" {units}" if units else "")
        label = f"{name} (RMSE {shown})"
        (line,) = axes[0].plot(t[:end], ys[:end], lw=0.5, label=label)
        axes[1].plot(t[:end], err, lw=0.5, label=name)
        if end:
            worst = max(worst, float(np.nanmax(np.abs(err))))
        if step is not None:
            axes[0].plot(
                [t[max(end - 1, 0)]],
                [np.clip(ys[max(end - 1, 0)], low, high)],
                "x",
                color=line.get_color(),
                ms=9,
                label=f"{name} diverged at step {n + step}",
            )
        which = np.clip(np.digitize(np.abs(y[:end]), edges[1:-1]), 0, 9)
        with warnings.catch_warnings():  # a bin whose outputs are all missing is NaN, without a warning
            warnings.simplefilter("ignore", RuntimeWarning)
            rms = [
                np.sqrt(np.nanmean(err[which == b] ** 2)) if np.any(which == b) else np.nan for b in range(10)
            ]
        axes[2].plot(0.5 * (edges[1:] + edges[:-1]), rms, marker="o", label=name)
    axes[0].set_ylim(low, high)
    if worst > 0:
        axes[1].set_ylim(-min(worst, 2 * span) * 1.05, min(worst, 2 * span) * 1.05)
    axes[0].set_ylabel(f"y{unit}")
    axes[1].set_ylabel(f"error{unit}")
    axes[2].set_xlabel(f"|measured output|{unit} (deciles)")
    axes[2].set_ylabel(f"RMS error{unit}")
    axes[1].set_xlabel("time [s]" if test.sampling_time else "step")
    axes[2].set_yscale("log")
    for ax in axes:
        ax.legend(fontsize=7)
    axes[0].set_title(f"{stem}: free-run simulation after {n} measured outputs")
    return save(fig, out_dir, stem)
