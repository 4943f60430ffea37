"""report.md tables and figures: built from a summary of predictors with known errors."""

import numpy as np
import pytest
import torch

from mop import plots
from mop.evaluate import evaluate, summarize
from mop.report import build_report, error_table, ratio_table, summary_section
from mop.systems.base import Trajectories


class Scaled:
    def __init__(self, name, scale):
        self.name, self.scale = name, scale

    def predict(self, traj):
        return traj.y * self.scale


def _summary():
    y = torch.randn(20, 51, 2, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    traj = Trajectories(y=y, u=None, x=None, family="linear")
    return summarize(evaluate([Scaled("mop", 0.5), Scaled("kalman", 0.6)], traj, progress=False), "kalman")


def test_tables_hold_every_predictor_and_window():
    s = _summary()
    table = error_table(s)
    rows = table.splitlines()
    assert len(rows) == 2 + 2 and rows[2].startswith("| mop |") and rows[3].startswith("| kalman |")
    mop_cells = [float(c) for c in rows[2].strip("|").split("|")[1:]]
    assert mop_cells == [round(v, 4) for v in s["predictors"]["mop"]["window_error"].values()]
    ratios = ratio_table(s)
    assert "| mop |" in ratios and "| kalman |" not in ratios and "bootstrap" in ratios
    text = build_report("t", [summary_section("linear", s, ["a.png"])], {"seed": 0}, ["- claim"], 1.5)
    assert table in text and "![a.png](a.png)" in text and "torch" in text and "Wall time: 1.5 s" in text


def test_ratio_panel_leaves_out_trivial_predictors():
    """A predictor 40 x the reference is left out of the ratio panel (named in its title); the axis is
    clipped at 1.5 x the panel predictors' 90th percentile, so ratios near 1 keep their room."""
    T = 51
    flat = {"error": [1.0] * T, "std": [0.1] * T}
    predictors = {
        "mop": {**flat, "squared_error": [1.2] * T},
        "kalman": {**flat, "squared_error": [1.0] * T},
        "zero": {**flat, "squared_error": [40.0] * T},
    }
    fig = plots.error_figure(predictors, ["mop", "kalman"], "kalman", "x")
    right = fig.axes[1]
    assert [line.get_label() for line in right.get_lines()] == ["mop", "kalman"]
    assert "zero" in right.get_title() and right.get_ylim()[1] == pytest.approx(2.0)
    assert plots.ratio_panel_top({"mop": np.array([1.0, 3.0] * 10)}) == pytest.approx(4.5)


def test_figures_written_nonempty(tmp_path):
    s = _summary()
    paths = plots.save(
        plots.error_figure(s["predictors"], ["mop", "kalman", "absent"], "kalman", "x"), tmp_path, "err"
    )
    paths += plots.save(plots.ratio_figure({"d": ([1, 2, 3], [1, 1, 2])}, "r"), tmp_path, "ratio")
    paths += plots.save(plots.matrix_power_figure({"d": [1, 2, 3]}, "m"), tmp_path, "pow")
    paths += plots.save(plots.noise_level_figure([0.01, 0.1], {"m": [0.2, 0.5]}, 0.1, "n"), tmp_path, "noise")
    paths += plots.save(plots.loglog_figure([10, 100], [1.0, 0.3], -0.5, 0.0, "M", "s"), tmp_path, "scale")
    assert len(paths) == 10
    for p in paths:
        assert p.stat().st_size > 1000, p
    assert sorted(x.name for x in tmp_path.iterdir()) == sorted(p.name for p in paths)  # no temp files left


def test_settings_show_long_lists_of_numbers_as_their_length():
    """A fitted prior (hundreds of numbers) shows as "<N numbers>"; short lists and others as they are."""
    prior = [0.5] * 300
    settings = {"train": {"model": {"rls_prior": prior, "width": 64}}, "predictors": ["mop", "kalman"]}
    settings["window"] = (20, 51)
    text = build_report("t", [], settings, [], 1.0)
    assert "'rls_prior': '<300 numbers>'" in text and "'width': 64" in text
    assert "predictors: ['mop', 'kalman']" in text and "window: (20, 51)" in text
    assert "0.5, 0.5" not in text
