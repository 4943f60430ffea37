"""Figures in the paper's style (matplotlib Agg): log-scale error against t with +-1 std bands.

Also the Fig. 4 panels, Fig. 5 and the scaling plots.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from mop.atomic import atomic_path  # noqa: E402


def save(fig, out_dir: Path, stem: str) -> list[Path]:
    """Write `stem`.png and `stem`.pdf atomically; returns the paths."""
    paths = []
    for ext in ("png", "pdf"):
        path = Path(out_dir) / f"{stem}.{ext}"
        with atomic_path(path) as tmp:
            fig.savefig(tmp, format=ext, dpi=150, bbox_inches="tight")
        paths.append(path)
    plt.close(fig)
    return paths


def ratio_panel_top(panel_ratios: dict[str, np.ndarray]) -> float:
    """Upper limit of the ratio panel: 1.5 x the largest 90th percentile over t of the panel predictors'
    ratios (T,) each, at least 2."""
    highest = max((float(np.quantile(r, 0.9)) for r in panel_ratios.values()), default=1.0)
    return max(2.0, 1.5 * highest)


def error_figure(
    predictors: dict[str, dict],
    panel: list[str],
    reference: str,
    title: str,
    floor_mse: list[float] | None = None,
    floor_norm: list[float] | None = None,
):
    """Two panels. Left, the paper's: mean error ||yhat_t - y_t|| against t (log scale) with +-1 std bands
    (floored above 0) for the `panel` predictors (those present), and, where given, the optimum in the same
    metric, E||e_t|| for e_t ~ N(0, S_t) of the known system (dashed). Right: the MSE ratio to the
    reference against t (log scale), its axis clipped at 1.5 x the largest 90th percentile (over t) of the
    panel predictors' ratios (at least 2), so trivial predictors such as `zero` (ratios up to 40) do not
    squash the range that matters; predictors whose median ratio lies above the clip are left out and named
    in the title. The floor's ratio is dashed."""
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4))
    colors = {name: f"C{i}" for i, name in enumerate(predictors)}
    for name in dict.fromkeys(n for n in panel if n in predictors):
        c = predictors[name]
        mean, std = np.asarray(c["error"]), np.asarray(c["std"])
        t = np.arange(len(mean))
        left.plot(t, mean, label=name, color=colors[name])
        left.fill_between(t, np.maximum(mean - std, mean * 0.05), mean + std, alpha=0.15, color=colors[name])
    if floor_norm is not None:
        left.plot(floor_norm, "k--", lw=0.9, label=r"optimum $E\|e_t\|$, $e_t \sim N(0, S_t)$")
    left.set(yscale="log", xlabel="t", ylabel=r"$\|\hat y_t - y_t\|_2$", title=title)
    left.legend(fontsize=8)
    left.grid(alpha=0.3, which="both")
    if reference in predictors:
        den = np.asarray(predictors[reference]["squared_error"][1:])
        ratios = {name: np.asarray(c["squared_error"][1:]) / den for name, c in predictors.items()}
        top = ratio_panel_top({n: r for n, r in ratios.items() if n in panel})
        left_out = [name for name, r in ratios.items() if np.median(r) > top]
        for name, ratio in ratios.items():
            if name not in left_out:
                right.plot(np.arange(1, len(ratio) + 1), ratio, label=name, color=colors[name], lw=1.2)
        if floor_mse is not None:
            right.plot(
                np.arange(1, len(den) + 1), np.asarray(floor_mse[1:]) / den, "k--", lw=0.9, label="floor"
            )
        dropped = f" (left out, median ratio > {top:.3g}: {', '.join(left_out)})" if left_out else ""
        right.set(yscale="log", xlabel="t", ylabel=f"MSE ratio to {reference}", title="predictors" + dropped)
        right.set_ylim(top=top)
        right.legend(fontsize=7, ncol=2)
        right.grid(alpha=0.3, which="both")
    fig.tight_layout()
    return fig


def ratio_figure(curves: dict[str, tuple[list[float], list[float]]], title: str):
    """MSE ratio model/KF against t for each family: {label: (mop squared_error, kf squared_error)}."""
    fig, ax = plt.subplots(figsize=(6, 4))
    for label, (num, den) in curves.items():
        ratio = np.asarray(num[1:]) / np.asarray(den[1:])
        ax.plot(np.arange(1, len(num)), ratio, label=label)
    ax.axhline(1.0, color="k", lw=0.8, ls="--")
    ax.set(yscale="log", xlabel="t", ylabel="MSE ratio MOP / KF", title=title)
    ax.legend(fontsize=8)
    return fig


def ratio_by_x_figure(
    xs: list[float],
    curves: dict[str, list[tuple[float, float, float]]],
    reference: str,
    axis: str,
    title: str,
):
    """MSE ratio to `reference` (with its CI as error bars) against a sweep value, one line per predictor:
    curves {name: [(ratio, low, high) per x]}."""
    fig, ax = plt.subplots(figsize=(6, 4))
    for name, points in curves.items():
        r = np.array(points)  # (len(xs), 3)
        ax.errorbar(
            xs, r[:, 0], yerr=[r[:, 0] - r[:, 1], r[:, 2] - r[:, 0]], marker="o", capsize=3, label=name
        )
    ax.axhline(1.0, color="k", lw=0.8, ls="--")
    ax.axhline(1.1, color="grey", lw=0.8, ls=":", label="1.1")
    ax.set(yscale="log", xlabel=axis, ylabel=f"MSE ratio to {reference}, t in [20, T]", title=title)
    ax.legend(fontsize=8)
    return fig


def matrix_power_figure(curves: dict[str, list[float]], title: str):
    """Average over systems of ||A^k|| / rho(A)^k against k for each family (Fig. 4b)."""
    fig, ax = plt.subplots(figsize=(6, 4))
    for label, values in curves.items():
        ax.plot(np.arange(len(values)), values, label=label)
    ax.set(yscale="log", xlabel="k", ylabel=r"mean $\|A^k\| / \rho(A)^k$", title=title)
    ax.legend(fontsize=8)
    return fig


def noise_level_figure(
    levels: list[float], errors: dict[str, list[float]], train_level: float | None, title: str
):
    """Mean error over t >= 1 against the test noise level sigma^2 (Fig. 5)."""
    fig, ax = plt.subplots(figsize=(6, 4))
    for name, values in errors.items():
        ax.plot(levels, values, marker="o", label=name)
    if train_level is not None:
        ax.axvline(train_level, color="k", lw=0.8, ls="--", label="training level")
    ax.set(
        xscale="log", yscale="log", xlabel=r"test noise variance $\sigma^2$", ylabel="mean error", title=title
    )
    ax.legend(fontsize=8)
    return fig


def loglog_figure(x: list[float], y: list[float], slope: float, intercept: float, xlabel: str, title: str):
    """Excess risk against M or T on log-log axes with the fitted line."""
    fig, ax = plt.subplots(figsize=(6, 4))
    x, y = np.asarray(x, float), np.asarray(y, float)
    ax.plot(x, y, "o", label="measured")
    ax.plot(x, np.exp(intercept) * x**slope, "-", label=f"fit, slope {slope:.2f}")
    ax.plot(x, y[0] * (x / x[0]) ** -0.5, ":", label="slope -1/2")
    ax.set(xscale="log", yscale="log", xlabel=xlabel, ylabel="excess MSE over KF", title=title)
    ax.legend(fontsize=8)
    return fig


def calibration_figure(levels: list[float], coverages: dict[str, list[float]], title: str):
    """Reliability diagram: empirical coverage of the central interval against its nominal level."""
    fig, ax = plt.subplots(figsize=(4.5, 4.5))
    ax.plot([0, 1], [0, 1], color="k", lw=0.8, ls="--", label="calibrated")
    for name, values in coverages.items():
        ax.plot(levels, values, marker=".", label=name)
    ax.set(xlabel="nominal level of the central interval", ylabel="empirical coverage", title=title)
    ax.set(xlim=(0, 1), ylim=(0, 1))
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return fig
