"""report.md: per-predictor error tables, MOP/reference MSE ratios with CIs.

The paper's claims are stated next to the numbers.
"""

from __future__ import annotations

import importlib.metadata
import platform
from typing import Any


def _versions() -> str:
    names = ("mop", "torch", "numpy", "scipy", "matplotlib")
    out = []
    for name in names:
        try:
            out.append(f"{name} {importlib.metadata.version(name)}")
        except importlib.metadata.PackageNotFoundError:
            out.append(f"{name} ?")
    return ", ".join(out) + f", python {platform.python_version()}"


def error_table(summary: dict) -> str:
    """Markdown table: each predictor's mean error ||yhat_t - y_t|| over the report windows."""
    preds = summary["predictors"]
    wins = list(next(iter(preds.values()))["window_error"])
    lines = [
        "| predictor | " + " | ".join(f"error t in {w}" for w in wins) + " |",
        "|---" * (len(wins) + 1) + "|",
    ]
    for name, c in preds.items():
        lines.append(f"| {name} | " + " | ".join(f"{c['window_error'][w]:.4f}" for w in wins) + " |")
    return "\n".join(lines)


def ratio_table(summary: dict) -> str:
    """Markdown table of MSE ratios predictor/reference with 95% bootstrap CIs."""
    info = summary["ratios_to_reference"]
    if not info["ratios"]:
        return ""
    wins = list(next(iter(info["ratios"].values())))
    spread = any(has_interval(r[w]) for r in info["ratios"].values() for w in wins)
    interval = "95% CI" if spread else "one record: no interval"
    lines = [
        f"MSE ratio to `{info['reference']}` ({info['method']}; {interval}):",
        "",
        "| predictor | " + " | ".join(f"t in {w}" for w in wins) + " |",
        "|---" * (len(wins) + 1) + "|",
    ]
    for name, r in info["ratios"].items():
        lines.append(f"| {name} | " + " | ".join(fmt_ratio(r[w]) for w in wins) + " |")
    return "\n".join(lines)


def has_interval(r: dict) -> bool:
    """Whether a ratio entry's bootstrap interval has a width (over one record it is the ratio itself)."""
    return r["low"] != r["high"]


def fmt_ratio(r: dict) -> str:
    """ratio [low, high], or the ratio alone where the interval has no width (one record)."""
    if not has_interval(r):
        return f"{r['ratio']:.3f}"
    return f"{r['ratio']:.3f} [{r['low']:.3f}, {r['high']:.3f}]"


def ratio(summary: dict, name: str, window_start: int) -> dict | None:
    """The ratio entry of `name` for the window starting at `window_start` (1, 10 or 20), if present."""
    r = summary["ratios_to_reference"]["ratios"].get(name, {})
    for w, value in r.items():
        if w != "all" and w.startswith(f"[{window_start},"):
            return value
    return None


def rmse_cell(value: float | None) -> str:
    """An RMSE for a table: 4 significant digits (an exact class's errors are near 1e-5, which 4 decimals
    would show as 0.0000), "-" where it is missing (a column added after the numbers were written)."""
    return "-" if value is None else f"{value:.4g}"


def claim_line(claim: str, evidence: str, holds: bool | None) -> str:
    verdict = {True: "supported", False: "not supported", None: "n/a"}[holds]
    return f"- **{claim}** — {evidence} ({verdict})"


SHOWN_NUMBERS = 12  # a longer list of numbers in the settings (a feature's fitted prior) shows as its length


def abridged(value: Any) -> Any:
    """value with every list or tuple of more than SHOWN_NUMBERS numbers, at any depth, replaced by the words
    "<N numbers>": the report stays readable; the run's config.json and eval.json keep them all."""
    if isinstance(value, dict):
        return {k: abridged(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        numbers = all(isinstance(x, int | float) and not isinstance(x, bool) for x in value)
        if numbers and len(value) > SHOWN_NUMBERS:
            return f"<{len(value)} numbers>"
        return type(value)(abridged(v) for v in value)
    return value


def build_report(
    title: str,
    sections: list[str],
    settings: dict,
    claims: list[str],
    wall_seconds: float,
    lead: str = "",
) -> str:
    """The report.md text: title, lead (a table that comes first), claims, sections (tables), settings,
    versions, wall time."""
    parts = [
        f"# {title}",
        "",
        *([lead] if lead else []),
        "## Claims against our numbers",
        "",
        *claims,
        "",
        *sections,
        "",
        "## Settings",
        "",
        "```",
        *[f"{k}: {abridged(v)}" for k, v in settings.items()],
        "```",
        "",
        f"Package versions: {_versions()}",
        "",
        f"Wall time: {wall_seconds:.1f} s",
        "",
    ]
    return "\n".join(parts)


def summary_section(heading: str, summary: dict, figures: list[str]) -> str:
    figs = "\n".join(f"![{f}]({f})" for f in figures if f.endswith(".png"))
    return "\n".join(
        [
            f"## {heading}",
            "",
            f"N = {summary['num_systems']} test systems, T = {summary['horizon']}.",
            "",
            "Mean error ||yhat_t - y_t||_2 over test systems:",
            "",
            error_table(summary),
            "",
            ratio_table(summary),
            "",
            figs,
            "",
        ]
    )


def forecast_markdown(forecast: dict) -> list[str]:
    """The forecast analysis's {"k", "start", "error": predictor -> errors per k} as markdown lines (the
    report's table, and the pretrained cards')."""
    ks = forecast["k"]
    lines = [
        f"k-step forecast error: mean ||y_(t+k-1) - forecast|| over origins t >= {forecast['start']}:",
        "",
        "| predictor | " + " | ".join(f"k={k}" for k in ks) + " |",
        "|---" * (len(ks) + 1) + "|",
    ]
    return lines + [
        f"| {n} | " + " | ".join(f"{e:.4f}" for e in errs) + " |" for n, errs in forecast["error"].items()
    ]


def simulation_cell(r: dict) -> str:
    """A predictor's simulation RMSE for a table: "diverged (k systems)" where k systems' free runs left the
    finite numbers (their mean is then inf), else the mean over systems."""
    if r.get("diverged_systems"):
        return f"diverged ({r['diverged_systems']} systems)"
    return f"{r['simulation_rmse']:.4g}"  # as rmse_cell
