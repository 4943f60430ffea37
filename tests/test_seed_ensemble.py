"""scripts/seed_ensemble.py: the mean of several `mop benchmark` runs' simulations of a test, scored as the
benchmark scores one (pooled RMSE over the scored steps), against numpy on the same arrays."""

import subprocess
import sys
from pathlib import Path

import numpy as np

from mop.commands.predict import write_simulation

SCRIPT = str(Path(__file__).resolve().parents[1] / "scripts" / "seed_ensemble.py")


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, SCRIPT, *args], capture_output=True, text=True)


def benchmark_out(folder: Path, y: np.ndarray, sim: np.ndarray, n: int) -> Path:
    """A `mop benchmark --out` folder holding one test's simulation of the "mop" row (its scored steps)."""
    (folder / "bench").mkdir(parents=True)
    write_simulation(folder / "bench" / "test_mop.csv", ["test"], [sim], n, [y])
    return folder


def test_the_mean_simulation_is_scored_as_one_predictor(tmp_path):
    rng = np.random.default_rng(0)
    n, y = 5, rng.normal(size=(105, 2))
    sims = [y[n:] + rng.normal(scale=0.1, size=(100, 2)) + 0.05 * k for k in range(3)]
    outs = [str(benchmark_out(tmp_path / f"s{k}", y, s, n)) for k, s in enumerate(sims)]
    done = run(*outs)
    assert done.returncode == 0, done.stderr
    rmse = lambda s: np.sqrt(np.mean((y[n:] - s) ** 2))  # noqa: E731
    each = " / ".join(f"{rmse(s):.4g}" for s in sims)
    line = f"bench test: runs {each}; their mean simulation {rmse(np.mean(sims, axis=0)):.4g}"
    assert done.stdout.strip() == line
    assert rmse(np.mean(sims, axis=0)) < min(rmse(s) for s in sims)  # independent errors average down


def test_runs_of_other_tests_are_refused_in_one_line(tmp_path):
    rng = np.random.default_rng(1)
    y = rng.normal(size=(60, 1))
    a = benchmark_out(tmp_path / "a", y, y[10:], 10)
    b = benchmark_out(tmp_path / "b", y + 1, y[10:], 10)
    done = run(str(a), str(b))
    assert done.returncode != 0 and "other measured outputs" in done.stderr
    assert "Traceback" not in done.stderr and len(done.stderr.strip().splitlines()) == 1
