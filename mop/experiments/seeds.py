"""Results over training seeds (`mop reproduce ... --seeds K`) and the one-table summary of `reproduce all`.

Each training seed s gives one eval.json (same test systems: the test seed is fixed). Per condition and per
ratio (MOP / the experiment's reference and MOP / the best predictor, MSE over t in [20, T]) this reports
every seed's ratio with its bootstrap CI over test systems, the mean over seeds and the range (min, max).
The bootstrap CI resamples test systems only; the range shows what a new training seed changes.
"""

from __future__ import annotations

from typing import Any

from mop.predictors import PREDICTORS, is_learned


def late_ratio(summary: dict) -> dict | None:
    """MOP (the first learned predictor) / reference over the window that starts at t = 20
    ({"ratio", "low", "high"}), or None."""
    by_predictor = summary.get("ratios_to_reference", {}).get("ratios", {})
    model = next((n for n in by_predictor if n in PREDICTORS and is_learned(n)), "")
    ratios = by_predictor.get(model, {})
    late = [w for w in ratios if w.startswith("[20,")]
    return ratios[late[0]] if late else None


def _spread(values: list[dict]) -> dict[str, Any]:
    ratios = [v["ratio"] for v in values]
    return {
        "mean": sum(ratios) / len(ratios),
        "min": min(ratios),
        "max": max(ratios),
        "per_seed": values,
    }


def seed_summary(evals: dict[int, dict]) -> dict[str, Any]:
    """{train seed: eval.json} -> {condition: {"reference": spread, "best": spread}} (spread: mean, min, max,
    per_seed [{"seed", "ratio", "low", "high"}]); a ratio missing under a condition is left out."""
    first = next(iter(evals.values()))
    out: dict[str, Any] = {}
    for condition in first["conditions"]:
        entry = {}
        ref = [(s, late_ratio(e["conditions"][condition])) for s, e in evals.items()]
        if all(r is not None for _, r in ref):
            entry["reference"] = _spread([{"seed": s, **_triple(r)} for s, r in ref])
            reference = first["conditions"][condition]["ratios_to_reference"]["reference"]
            entry["reference"]["predictor"] = reference
        best = [(s, e["conditions"][condition].get("to_best")) for s, e in evals.items()]
        if all(b is not None for _, b in best):
            entry["best"] = _spread([{"seed": s, **_triple(b)} for s, b in best])
            entry["best"]["predictor"] = best[0][1]["predictor"]
        if entry:
            out[condition] = entry
    return out


def _triple(r: dict) -> dict[str, float]:
    return {"ratio": r["ratio"], "low": r["low"], "high": r["high"]}


def _cell(spread: dict) -> str:
    cis = ", ".join(f"{v['ratio']:.3f} [{v['low']:.3f}, {v['high']:.3f}]" for v in spread["per_seed"])
    return f"{spread['mean']:.3f} [{spread['min']:.3f}, {spread['max']:.3f}] | {cis}"


def seeds_table(experiment: str, summary: dict[str, Any]) -> str:
    """Markdown: per condition and ratio, the mean over seeds, the range, each seed's ratio and CI."""
    lines = [
        f"## {experiment}: MSE ratios over t in [20, T] across training seeds",
        "",
        "| condition | ratio | mean [min, max over seeds] | each seed: ratio [95% CI over test systems] |",
        "|---|---|---|---|",
    ]
    for condition, entry in summary.items():
        shown = set()  # where the best predictor is the reference, one row
        for kind in ("best", "reference"):
            if kind in entry and entry[kind]["predictor"] not in shown:
                shown.add(entry[kind]["predictor"])
                label = f"MOP / {entry[kind]['predictor']}"
                lines.append(f"| {condition} | {label} | {_cell(entry[kind])} |")
    return "\n".join(lines) + "\n"


def lead_table(rows: list[dict[str, Any]]) -> str:
    """The summary of `reproduce all`: one row per experiment, MOP / best beside the authors' number.

    rows: {"experiment", "best" (spread of the first condition's MOP / best, or None), "authors"}.
    """
    lines = [
        "| experiment | yardstick | MOP / yardstick, t in [20,T]: mean [min, max over seeds] | seeds: ratio "
        "[95% CI] | the authors |",
        "|---|---|---|---|---|",
    ]
    for row in rows:
        spread = row["best"]
        if spread is None:
            lines.append(f"| {row['experiment']} | - | - | - | {row['authors'] or '-'} |")
            continue
        authors = row["authors"] or "-"
        lines.append(f"| {row['experiment']} | {spread['predictor']} | {_cell(spread)} | {authors} |")
    return "\n".join(lines) + "\n"
