"""Figures an experiment asks for by name, each a registered function writing PNG + PDF into `out`.

    paths = FIGURES.get("error")(exp, results, out)

No figure styles a predictor by its name: colours follow the order of the experiment's predictor list,
and figures read the analyses' extras through the analyses' own accessors.
"""

from __future__ import annotations

from pathlib import Path

from mop import plots
from mop.experiments.analyses import (
    calibration_table,
    floor_curve,
    floor_mean_norm,
    forecast_table,
    power_ratio,
    slope_fit,
    sweep_axes,
)
from mop.experiments.results import ConditionResult, Results
from mop.experiments.spec import Experiment
from mop.predictors import first_learned
from mop.registry import Registry

FIGURES: Registry = Registry("figure", keys={"default": "drawn when an experiment names no figures"})


def _stem(exp: Experiment, results: Results, condition: str, suffix: str) -> str:
    return (
        f"{exp.name}_{suffix}" if len(results) == 1 else f"{exp.name}_{condition}_{suffix}".replace(" ", "_")
    )


def figure_names(exp: Experiment) -> tuple[str, ...]:
    """The figures `exp` draws: its own list, or (None) the figures registered with default=True."""
    return tuple(FIGURES.flagged("default")) if exp.figures is None else tuple(exp.figures)


@FIGURES.register("error", default=True)
def error(exp: Experiment, results: Results, out: Path) -> list[Path]:
    """Per condition: the paper's panel (error with +-1 std bands) beside every predictor's MSE ratio."""
    paths = []
    for name, r in results.items():
        panel = [p or exp.reference for p in exp.panel]
        title = f"{exp.name} ({exp.title})" + ("" if len(results) == 1 else f", {name}")
        fig = plots.error_figure(
            r.summary["predictors"], panel, exp.reference, title, floor_curve(r), floor_mean_norm(r)
        )
        paths += plots.save(fig, out, _stem(exp, results, name, "error"))
    return paths


@FIGURES.register("ratio_by_condition")
def ratio_by_condition(exp: Experiment, results: Results, out: Path) -> list[Path]:
    """Fig. 4a: MOP / reference MSE ratio against t, one line per condition."""
    curves = {
        name: (
            r.summary["predictors"][first_learned(r.summary["predictors"])]["squared_error"],
            r.summary["predictors"][exp.reference]["squared_error"],
        )
        for name, r in results.items()
    }
    return plots.save(plots.ratio_figure(curves, f"{exp.title}: MOP / {exp.reference}"), out, "fig4a_ratio")


@FIGURES.register("ratio_by_x")
def ratio_by_x(exp, results: dict, out: Path) -> list[Path]:
    """Each predictor's MSE ratio to the reference over t in [20, T] (95% bootstrap CI) against the
    conditions' sweep value x (conditions without x are left out)."""
    points = [r for r in results.values() if r.condition.x]
    if not points:
        return []
    xs = [r.condition.x[1] for r in points]
    curves: dict[str, list[tuple[float, float, float]]] = {}
    for r in points:
        horizon = r.summary["horizon"]
        for name, wins in r.summary["ratios_to_reference"]["ratios"].items():
            w = wins.get(f"[20,{horizon + 1})", wins["all"])
            curves.setdefault(name, []).append((w["ratio"], w["low"], w["high"]))
    fig = plots.ratio_by_x_figure(xs, curves, exp.reference, points[0].condition.x[0], exp.title)
    return plots.save(fig, out, f"{exp.name}_ratio")


@FIGURES.register("matrix_powers")
def matrix_powers(exp: Experiment, results: Results, out: Path) -> list[Path]:
    """Fig. 4b: mean ||A^k|| / rho(A)^k against k, one line per condition."""
    curves = {name: power_ratio(r) for name, r in results.items() if power_ratio(r) is not None}
    return plots.save(plots.matrix_power_figure(curves, f"{exp.title}b"), out, "fig4b_powers")


def trained_level(exp: Experiment, point: ConditionResult) -> float | None:
    """The training value of what a sweep condition varies: the experiment's `train` value of the first
    system setting the condition overrides (e.g. the noise variance trained at), None if it trains none."""
    for key in point.condition.system:
        if f"system.{key}" in exp.train:
            return exp.train[f"system.{key}"]
    return None


@FIGURES.register("noise_levels")
def noise_levels(exp: Experiment, results: Results, out: Path) -> list[Path]:
    """Fig. 5: each predictor's mean error over all t against the conditions' sweep value."""
    points = [r for r in results.values() if r.condition.x]
    names = list(points[0].summary["predictors"])
    curves = {n: [r.summary["predictors"][n]["window_error"]["all"] for r in points] for n in names}
    levels = [r.condition.x[1] for r in points]
    train_level = trained_level(exp, points[0])
    fig = plots.noise_level_figure(levels, curves, train_level, f"{exp.title}: {points[0].condition.x[0]}")
    return plots.save(fig, out, "fig5_noise_shift")


@FIGURES.register("calibration")
def calibration(exp: Experiment, results: Results, out: Path) -> list[Path]:
    """Reliability diagram per condition: empirical against nominal coverage of central intervals."""
    paths = []
    for name, r in results.items():
        table = calibration_table(r)
        if not table:
            continue
        levels = next(iter(table.values()))["levels"]
        curves = {p: row["coverage"] for p, row in table.items()}
        paths += plots.save(
            plots.calibration_figure(levels, curves, f"{name}: interval coverage"), out, f"calibration_{name}"
        )
    return paths


@FIGURES.register("loglog")
def loglog(exp: Experiment, results: Results, out: Path) -> list[Path]:
    """Excess MSE against each sweep axis on log-log axes with the fitted slope."""
    paths = []
    for axis in sweep_axes(results):
        fit = slope_fit(results, axis)
        fig = plots.loglog_figure(
            fit["values"], fit["excess_mse"], fit["slope"], fit["intercept"], axis, f"excess risk vs {axis}"
        )
        paths += plots.save(fig, out, f"scaling_{axis}")
    return paths


@FIGURES.register("forecast")
def forecast(exp: Experiment, results: Results, out: Path) -> list[Path]:
    """Per condition: k-step forecast error against k, one line per predictor (the "forecast" analysis)."""
    import matplotlib.pyplot as plt

    paths = []
    for name, r in results.items():
        table = forecast_table(r)
        if not table:
            continue
        fig, ax = plt.subplots(figsize=(4.5, 3.2))
        for pred, errs in table["error"].items():
            ax.plot(table["k"], errs, marker="o", ms=3, label=pred)
        ax.set_xlabel("steps ahead k")
        ax.set_ylabel(f"mean ||y - yhat|| over t >= {table['start']}")
        ax.set_title(f"{exp.name}: k-step forecasts" + ("" if len(results) == 1 else f", {name}"))
        ax.legend(fontsize=7)
        fig.tight_layout()
        paths += plots.save(fig, out, _stem(exp, results, name, "forecast"))
    return paths
