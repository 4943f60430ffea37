"""CARD.md of a shipped model, rendered from its card.json alone (so the card's numbers are the build's).

card.json (written by mop.experiments.pretrained_build):
    name, summary, not_for, rebuild (the command)
    family        the trained family's SystemConfig (the data distribution)
    model         the ModelConfig; num_parameters; size_bytes of model.safetensors
    recipe        {"preset", "experiment", "condition", "train": TrainConfig}; seed; steps
    train_seconds, machine
    evaluation    {"num_systems", "test_seed", "horizon", "reference", "best",
                   "errors": {predictor: {window: mean ||e||}},
                   "ratio_to_reference" / "ratio_to_best": {window: {"ratio", "low", "high"}}}
    forecast      {"k", "start", "error": {predictor: [mean ||e|| per k]}} or null (a class model)
    simulation    {"context", "rmse": {predictor: {"one_step_rmse", "simulation_rmse"}}} or null/absent
    noise_shift   {"trained": {"noise_var_w", "noise_var_v"}, "num_systems", "rows": [{"factor",
                   "noise_var_w", "noise_var_v", "ratio", "low", "high"}]} or null
    sha256        {file: digest}
"""

from __future__ import annotations

from typing import Any

from mop.report import forecast_markdown, rmse_cell, simulation_cell


def _ci(r: dict[str, float]) -> str:
    return f"{r['ratio']:.3f} [{r['low']:.3f}, {r['high']:.3f}]"


def _settings(settings: dict[str, Any]) -> str:
    return ", ".join(f"{k} = {v}" for k, v in settings.items())


def _seconds(value: float | None) -> str:
    return "unknown (trained elsewhere or resumed)" if value is None else f"{value:.0f} s"


def _ratio_table(ev: dict[str, Any]) -> list[str]:
    """Errors and MSE ratios per window; the best predictor's columns only when it is not the reference."""
    ref, best, errs = ev["reference"], ev["best"], ev["errors"]
    other = best != ref
    head = f"| window | MOP error | {ref} error | MOP/{ref} MSE (95% CI) |"
    head += f" {best} error | MOP/{best} MSE (95% CI) |" if other else ""
    lines = [head, "|---" * (6 if other else 4) + "|"]
    for window, r in ev["ratio_to_reference"].items():
        row = f"| t in {window} | {errs['mop'][window]:.4f} | {errs[ref][window]:.4f} | {_ci(r)} |"
        if other:
            row += f" {errs[best][window]:.4f} | {_ci(ev['ratio_to_best'][window])} |"
        lines.append(row)
    return lines


def _simulation_table(sim: dict[str, Any] | None) -> list[str]:
    """The free-run simulation table of a class model's card (RMSE in the test records' units)."""
    if not sim:
        return []
    c = sim["context"]
    lines = [
        f"Free-run simulation of y_{c}..y_T from the inputs alone after a context of {c} outputs (RMSE per "
        "system, averaged), beside the one-step RMSE over the same steps and over t >= 50 (cards built "
        "before that column show -):",
        "",
        "| predictor | one-step RMSE | simulation RMSE | one-step RMSE, t >= 50 |",
        "|---|---|---|---|",
    ]
    for n, r in sim["rmse"].items():
        record = rmse_cell(r.get("one_step_rmse_record"))  # absent from cards built before it
        lines.append(f"| {n} | {rmse_cell(r['one_step_rmse'])} | {simulation_cell(r)} | {record} |")
    return [*lines, ""]


def _noise_table(shift: dict[str, Any] | None, reference: str) -> list[str]:
    if not shift:
        return ["The family has no noise-level knobs; no noise-shift numbers."]
    trained = shift["trained"]
    lines = [
        f"Noise shift: MOP/{reference} MSE over t >= 20 on {shift['num_systems']} test systems at other "
        f"noise variances (trained at w {trained['noise_var_w']:g}, v {trained['noise_var_v']:g}):",
        "",
        "| test variance / trained | noise_var_w | noise_var_v | MOP/ref MSE (95% CI) |",
        "|---|---|---|---|",
    ]
    lines += [
        f"| {r['factor']:g} | {r['noise_var_w']:g} | {r['noise_var_v']:g} | {_ci(r)} |" for r in shift["rows"]
    ]
    return lines


def _features(model: dict[str, Any]) -> str:
    """The card's clause naming the model's input features (mop.models.features); empty if plain."""
    parts = ["the running output scale"] if model.get("input_scale", "none") == "running" else []
    if model.get("record_norm", "none") == "causal":
        parts.append("each record normalised by its causal running mean and std (any units)")
    p, q = model.get("rls_order", 0), model.get("arx_order", 0)
    if p:
        fit = f"ARX({p}, {q})" if q else f"RLS-AR({p})"
        offset = " with an offset" if model.get("rls_offset") else ""
        scaled = {
            "running": ", its correction scaled by that prediction's recent error",
            "measured": ", its correction scaled by that prediction's recent error where outputs are "
            "measured (by the record's std across a gap)",
        }.get(model.get("residual_scale", "none"), "")
        parts.append(f"the {fit} one-step prediction{offset}{scaled}")
    return f", reads {' and '.join(parts)}" if parts else ""


def _gap_loss(model: dict[str, Any]) -> str:
    """The clause for model.gap_loss = "balanced"; empty for "pooled"."""
    if model.get("gap_loss", "pooled") != "balanced":
        return ""
    return (
        ", trained on the geometric mean of its one-step and its simulated positions' MSEs (model.gap_loss)"
    )


def _trained_on(card: dict[str, Any]) -> list[str]:
    """The card's "Trained on" list: family, model, recipe, seed and steps, machine."""
    recipe, machine, model = card["recipe"], card["machine"] or {}, card["model"]
    return [
        f"- family: {card['family']['family']} ({_settings(card['family'])})",
        f"- model: {model['arch']} {model['num_layers']} layers x {model['width']} wide, "
        f"{model['num_heads']} heads, context {model['context']}, read-out {model['readout']}, input "
        f"{model['input_dim']} -> output {model['output_dim']}{_features(model)}{_gap_loss(model)}; "
        f"{card['num_parameters']} parameters, "
        f"{card['size_bytes']} bytes of weights",
        f"- recipe: preset `{recipe['preset']}` of experiment `{recipe['experiment']}`"
        + (f" (condition `{recipe['condition']}`)" if recipe["condition"] else "")
        + f": {_settings(recipe['train'])}",
        f"- seed {card['seed']}, {card['steps']} steps, training time {_seconds(card['train_seconds'])}",
        f"- machine: {machine.get('cpu', 'unknown')}, {machine.get('cores', '?')} cores, torch "
        f"{machine.get('torch', '?')} with {machine.get('torch_threads', '?')} threads, Python "
        f"{machine.get('python', '?')}",
    ]


def _measured(ev: dict[str, Any]) -> str:
    """The sentence above the card's ratio table: the test systems, the reference and the best predictor."""
    return (
        f"{ev['num_systems']} fresh test systems (test seed {ev['test_seed']}, horizon {ev['horizon']}); "
        f"reference `{ev['reference']}`, best predictor `{ev['best']}` (the experiment's: the optimum where "
        "one exists, else the best filter that knows the system; otherwise the reference); "
        "errors are means of ||yhat_t - y_t||, ratios are MSE ratios with paired bootstrap 95% intervals "
        "over systems."
    )


def render_card(card: dict[str, Any]) -> str:
    """The CARD.md text of `card` (card.json's content)."""
    ev = card["evaluation"]
    lines = [
        f"# pretrained:{card['name']}",
        "",
        card["summary"] + ".",
        "",
        "## Trained on",
        "",
        *_trained_on(card),
        "",
        "## Measured",
        "",
        _measured(ev),
        "",
        *_ratio_table(ev),
        "",
        *(forecast_markdown(card["forecast"]) if card["forecast"] else []),
        *_simulation_table(card.get("simulation")),
        "",
        "## Where not to use it",
        "",
        f"On {card['not_for']}. Loading refuses data of other output or input dimensions.",
        "",
        *_noise_table(card["noise_shift"], ev["reference"]),
        "",
        "## Rebuild",
        "",
        "```",
        card["rebuild"],
        "```",
        "",
        "SHA-256 (checked on every load): "
        + ", ".join(f"{name} {digest[:16]}..." for name, digest in card["sha256"].items()),
        "",
    ]
    return "\n".join(lines)
