"""mop reproduce EXPERIMENT [--preset paper|small|smoke] [--out DIR] [--seed S]

Train (or reuse), evaluate, report.

DIR holds run/ (the trained MOP; a finished run is reused), run-gru/ (the GRU baseline), eval.json, figures
(PNG + PDF) and report.md. `all` runs every experiment into DIR/<experiment>/. `switching` (the paper tests
the plain linear model there) and `upper-triangular` (dense panel of Fig. 4a) train or reuse the linear model
in the sibling directory DIR/../linear/.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np
import torch

from mop.atomic import write_json, write_text
from mop.config import SystemConfig, to_dict
from mop.evaluate import evaluate, make_baseline, summarize
from mop.experiments import (
    EXPERIMENTS,
    NAMES,
    TEST_SEED_OFFSET,
    Experiment,
    get_experiment,
    get_preset,
    run_config,
)
from mop.metrics import coverage, gaussian_nll, loglog_slope, matrix_power_ratio
from mop.plots import (
    calibration_figure,
    error_figure,
    loglog_figure,
    matrix_power_figure,
    noise_level_figure,
    ratio_figure,
    save,
)
from mop.report import build_report, claim_line, ratio, summary_section

LINEAR_FAMILIES = ("linear", "upper-triangular", "colored-noise", "switching")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("experiment", choices=[*NAMES, "all"], help="the paper's experiment to reproduce")
    parser.add_argument(
        "--preset",
        choices=["paper", "small", "smoke"],
        default=None,
        help="paper (GPU default), small (laptop CPU default), smoke (< 60 s)",
    )
    parser.add_argument(
        "--out", default=None, help="output directory (default runs/reproduce/PRESET/EXPERIMENT)"
    )
    parser.add_argument("--seed", type=int, default=0, help="training seed; test systems use seed + 7000001")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")


def run(args: argparse.Namespace) -> int:
    preset = args.preset or ("paper" if torch.cuda.is_available() else "small")
    names = list(NAMES) if args.experiment == "all" else [args.experiment]
    root = Path(args.out) if args.out else Path("runs/reproduce") / preset
    for name in names:
        out = root / name if (args.experiment == "all" or not args.out) else root
        report = reproduce(name, preset, out, seed=args.seed, progress=not args.quiet)
        print(f"mop reproduce {name} ({preset}): report at {report}")
    return 0


def reproduce(name: str, preset: str, out: Path, seed: int = 0, progress: bool = True) -> Path:
    """Run one experiment into `out`; returns the path of report.md."""
    get_preset(preset)
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    if name == "scaling":
        summary, sections, claims, settings = _scaling(preset, out, seed, progress)
    else:
        exp = get_experiment(name)
        runner = {
            "upper-triangular": _upper_triangular,
            "noise-shift": _noise_shift,
            "calibration": _calibration,
        }.get(name, _standard)
        summary, sections, claims, settings = runner(exp, preset, out, seed, progress)
    summary = {"experiment": name, "preset": preset, **summary, "seed": seed, "settings": settings}
    write_json(out / "eval.json", summary)
    title = (
        f"mop reproduce {name} ({EXPERIMENTS[name].figure if name in EXPERIMENTS else 'Theorem 1'}), "
        f"preset {preset}"
    )
    text = build_report(
        title,
        sections,
        {"seed": seed, "test seed": seed + TEST_SEED_OFFSET, **settings},
        claims,
        time.perf_counter() - start,
    )
    write_text(out / "report.md", text)
    return out / "report.md"


# ----------------------------------------------------------------------------- building blocks


def _test_trajectories(system: SystemConfig, num_systems: int, horizon: int, seed: int):
    from mop.systems import generator, make_family

    family = make_family(system, dtype=torch.float64)
    return family.generate(num_systems, horizon, generator=generator(seed + TEST_SEED_OFFSET))


def _train(exp: Experiment, preset: str, run_dir: Path, seed: int, progress: bool, arch: str = "gpt") -> Path:
    from mop.train import train

    return train(run_config(exp, preset, seed, arch), run_dir, progress=progress)


def _learned(run_dir: Path, name: str, mode: str):
    from mop.runs import load_predictor

    predictor = load_predictor(run_dir, mode=mode)
    predictor.name = name
    return predictor


def _predictors(exp: Experiment, preset: str, out: Path, seed: int, progress: bool) -> list:
    """MOP (and the GRU) trained in `out`, or in the sibling experiment's directory, plus the baselines."""
    p = get_preset(preset)
    runs = out.parent / exp.shares_runs_with if exp.shares_runs_with else out
    predictors = [_learned(_train(exp, preset, runs / "run", seed, progress), "mop", exp.model_mode)]
    if p.train_gru:
        predictors.append(
            _learned(_train(exp, preset, runs / "run-gru", seed, progress, "gru"), "gru", "window")
        )
    return predictors + [make_baseline(b, n4sid_every=p.n4sid_every, seed=seed) for b in exp.baselines]


def _settings(exp: Experiment, preset: str, seed: int) -> dict:
    cfg = run_config(exp, preset, seed)
    return {
        "train": to_dict(cfg),
        "test_system": to_dict(exp.test_system),
        "test_horizon": exp.test_horizon,
        "num_test_systems": get_preset(preset).num_test_systems,
        "baselines": list(exp.baselines),
    }


def _evaluate_setting(exp, system, predictors, preset, seed, progress) -> dict:
    traj = _test_trajectories(system, get_preset(preset).num_test_systems, exp.test_horizon, seed)
    return summarize(evaluate(predictors, traj, progress), reference=exp.reference, seed=seed)


def _standard_claims(exp: Experiment, s: dict) -> list[str]:
    ref = exp.reference.upper()
    late, early = ratio(s, "mop", 20), ratio(s, "mop", 1)
    claims = []
    if late:
        target = {"linear": 1.05, "switching": 1.1}.get(exp.name)
        text = (
            f"MOP/{ref} MSE ratio over t >= 20 = {late['ratio']:.3f} [{late['low']:.3f}, {late['high']:.3f}]"
        )
        if exp.name in ("linear", "switching"):
            claims.append(claim_line(f"MOP matches the {ref} after ~20 steps", text, late["ratio"] <= target))
        elif exp.name in ("colored-noise", "quadrotor"):
            claims.append(
                claim_line(f"MOP beats the {ref}, which is misspecified here", text, late["high"] < 1)
            )
        elif exp.name == "upper-triangular":
            claims.append(
                claim_line(
                    "MOP is clearly worse than the KF on upper-triangular systems", text, late["low"] > 1.05
                )
            )
    if early:
        claims.append(
            claim_line(
                "MOP is worse than the optimal filter in the first steps (t <= 10)",
                f"ratio over [1,10] = {early['ratio']:.3f} [{early['low']:.3f}, {early['high']:.3f}]",
                early["ratio"] > 1 if exp.name == "linear" else None,
            )
        )
    preds = s["predictors"]
    if exp.name == "switching":
        after = {n: np.mean(preds[n]["error"][70:]) for n in ("mop", "kalman", "kalman-switch")}
        text = ", ".join(f"{n} {v:.4f}" for n, v in after.items())
        claims.append(
            claim_line(
                "after the switch MOP re-adapts, while the KF that keeps system 1 does not",
                f"mean error over t in [70,100]: {text}",
                bool(after["mop"] < after["kalman"]),
            )
        )
    for other in ("n4sid-kf", "rls-best"):
        if other in preds:
            m = np.mean(preds["mop"]["error"][1:20])
            o = np.mean(preds[other]["error"][1:20])
            claims.append(
                claim_line(
                    f"MOP's error is below {other} over t in [1,20)",
                    f"MOP {m:.4f} vs {other} {o:.4f}",
                    bool(m < o),
                )
            )
    return claims


def _standard(exp: Experiment, preset: str, out: Path, seed: int, progress: bool):
    predictors = _predictors(exp, preset, out, seed, progress)
    s = _evaluate_setting(exp, exp.test_system, predictors, preset, seed, progress)
    figs = save(error_figure(s["predictors"], f"{exp.name} ({exp.figure})"), out, f"{exp.name}_error")
    section = summary_section(exp.name, s, [f.name for f in figs])
    return s, [section], _standard_claims(exp, s), _settings(exp, preset, seed)


# ----------------------------------------------------------------------------- special experiments


def _upper_triangular(exp: Experiment, preset: str, out: Path, seed: int, progress: bool):
    s, sections, claims, settings = _standard(exp, preset, out, seed, progress)
    dense = get_experiment("linear")
    dense_dir = (
        out.parent / "linear" / "run"
    )  # the sibling linear run: reused when finished, else trained there
    dense_mop = _learned(_train(dense, preset, dense_dir, seed, progress), "mop", "window")
    d = _evaluate_setting(
        dense, dense.test_system, [dense_mop, make_baseline("kalman")], preset, seed, progress
    )
    ratio_fig = ratio_figure(
        {
            "dense (linear)": (
                d["predictors"]["mop"]["squared_error"],
                d["predictors"]["kalman"]["squared_error"],
            ),
            "upper-triangular": (
                s["predictors"]["mop"]["squared_error"],
                s["predictors"]["kalman"]["squared_error"],
            ),
        },
        "Fig. 4a",
    )
    n = get_preset(preset).num_test_systems
    powers = {
        fam: matrix_power_ratio(
            _test_trajectories(SystemConfig(family=fam), n, 1, seed).params["A"], 50
        ).tolist()
        for fam in ("linear", "upper-triangular")
    }
    figs = save(ratio_fig, out, "fig4a_ratio") + save(
        matrix_power_figure(powers, "Fig. 4b"), out, "fig4b_powers"
    )
    s["dense"] = d
    s["matrix_power_ratio"] = powers
    sections.append(summary_section("dense linear (for Fig. 4a)", d, [f.name for f in figs]))
    late_d, late_u = ratio(d, "mop", 20), ratio(s, "mop", 20)
    claims.append(
        claim_line(
            "upper-triangular systems are harder for MOP than dense ones",
            f"MOP/KF ratio t >= 20: dense {late_d['ratio']:.3f}, upper-triangular {late_u['ratio']:.3f}",
            late_u["ratio"] > late_d["ratio"],
        )
    )
    claims.append(
        claim_line(
            "||A^k|| / rho(A)^k grows far larger for upper-triangular A (transient growth)",
            f"max over k: dense {max(powers['linear']):.3g}, upper-triangular "
            f"{max(powers['upper-triangular']):.3g}",
            max(powers["upper-triangular"]) > max(powers["linear"]),
        )
    )
    return s, sections, claims, settings


def _noise_shift(exp: Experiment, preset: str, out: Path, seed: int, progress: bool):
    predictors = _predictors(exp, preset, out, seed, progress)
    levels, sections = {}, []
    for level in exp.test_noise_levels:
        system = dataclasses.replace(exp.test_system, noise_var_w=level, noise_var_v=level)
        levels[str(level)] = {
            "experiment": exp.name,
            "preset": preset,
            "noise_var": level,
            **_evaluate_setting(exp, system, predictors, preset, seed, progress),
        }
        sections.append(summary_section(f"test noise variance {level}", levels[str(level)], []))
    names = list(next(iter(levels.values()))["predictors"])
    curves = {n: [v["predictors"][n]["window_error"]["all"] for v in levels.values()] for n in names}
    figs = save(
        noise_level_figure(list(exp.test_noise_levels), curves, exp.train_system.noise_var_w, "Fig. 5"),
        out,
        "fig5_noise_shift",
    )
    sections.insert(0, "\n".join(f"![{f.name}]({f.name})" for f in figs if f.suffix == ".png"))
    r = {lv: ratio(v, "mop", 20)["ratio"] for lv, v in levels.items()}
    claims = [
        claim_line(
            "MOP trained at sigma^2 = 0.1 stays close to the KF at other test noise levels",
            "MOP/KF ratio t >= 20 per level: " + ", ".join(f"{k}: {v:.3f}" for k, v in r.items()),
            max(r.values()) < 1.5,
        )
    ]
    first = next(iter(levels.values()))
    return (
        {
            "num_systems": first["num_systems"],
            "horizon": first["horizon"],
            "predictors": first["predictors"],
            "levels": levels,
        },
        sections,
        claims,
        _settings(exp, preset, seed),
    )


def _calibration(exp: Experiment, preset: str, out: Path, seed: int, progress: bool):
    from mop.filters.kalman import kalman_filter

    results, sections, claims = {}, [], []
    for family in ("linear", "colored-noise"):
        fam_exp = dataclasses.replace(
            exp, train_system=SystemConfig(family=family), test_system=SystemConfig(family=family)
        )
        model = _learned(_train(fam_exp, preset, out / f"run-{family}", seed, progress), "mop", "window")
        traj = _test_trajectories(
            fam_exp.test_system, get_preset(preset).num_test_systems, exp.test_horizon, seed
        )
        mean, var = model.predict_distribution(traj)  # (N, T+1, m) each
        p = traj.params
        kf = kalman_filter(p["A"], p["C"], p["Q"], p["R"], traj.y, P0=p["P0"])
        kf_var = torch.diagonal(kf.S, dim1=-2, dim2=-1)  # (N, T+1, m)
        y = traj.y[:, 1:]
        # predictive mean and variance of y_t for t >= 1, (N, T, m) each
        dists = {"mop": (mean[:, 1:], var[:, 1:]), "kalman": (kf.yhat[:, 1:], kf_var[:, 1:])}
        row = {}
        for name, (mu, v) in dists.items():
            row[name] = {
                "nll": gaussian_nll(y, mu, v),
                **{f"coverage_{int(q * 100)}": coverage(y, mu, v, q) for q in (0.5, 0.9, 0.95)},
            }
        results[family] = row
        levels = [round(q, 2) for q in np.arange(0.05, 1.0, 0.05)]
        curves = {name: [coverage(y, mu, v, q) for q in levels] for name, (mu, v) in dists.items()}
        figs = save(
            calibration_figure(levels, curves, f"{family}: interval coverage"), out, f"calibration_{family}"
        )
        lines = [
            f"## {family}",
            "",
            "| predictor | NLL | coverage 50% | 90% | 95% |",
            "|---|---|---|---|---|",
        ]
        lines += [
            f"| {n} | {r['nll']:.4f} | {r['coverage_50']:.3f} | {r['coverage_90']:.3f} | "
            f"{r['coverage_95']:.3f} |"
            for n, r in row.items()
        ]
        lines += ["", *(f"![{f.name}]({f.name})" for f in figs if f.suffix == ".png")]
        sections.append("\n".join(lines))
        cov = row["mop"]["coverage_90"]
        claims.append(
            claim_line(
                f"{family}: MOP's 90% interval covers 88-92% of test outputs",
                f"coverage {cov:.3f} (KF {row['kalman']['coverage_90']:.3f})",
                0.88 <= cov <= 0.92 if family == "linear" else None,
            )
        )
    lin = results["linear"]
    summary = {
        "num_systems": get_preset(preset).num_test_systems,
        "horizon": exp.test_horizon,
        "predictors": {},
        "calibration": results,
        "note": f"NLL averages t >= 1; KF variance diag(S_t); mop NLL {lin['mop']['nll']:.4f}",
    }
    return summary, sections, claims, _settings(exp, preset, seed)


SCALING_GRID = {
    "smoke": ((32, 128, 512), (20, 35, 50), 30),
    "small": ((250, 1000, 4000), (20, 50, 100), 600),
    "paper": ((1000, 4000, 16000), (20, 50, 100), 10000),
}


def _scaling(preset: str, out: Path, seed: int, progress: bool):
    """Excess MSE of MOP over the oracle KF against M (T = 50) and against T (M fixed).

    Log-log slope +- OLS standard error."""
    from scipy.stats.distributions import t as student_t

    t_quantile = student_t.ppf  # scipy.stats imported here, not at `mop` start-up
    M_values, T_values, steps = SCALING_GRID[preset]
    p = get_preset(preset)
    base = get_experiment("linear")
    results, sections, claims = {}, [], []
    for axis, values in (("M", M_values), ("T", T_values)):
        excess = []
        for v in values:
            M, T = (v, 50) if axis == "M" else (M_values[-1], v)
            cfg = run_config(base, "smoke" if preset != "paper" else preset, seed)
            cfg = dataclasses.replace(
                cfg,
                model=dataclasses.replace(cfg.model, context=T, num_layers=2, width=64, num_heads=4)
                if preset != "paper"
                else dataclasses.replace(cfg.model, context=T),
                train=dataclasses.replace(
                    cfg.train, num_source_systems=M, horizon=T, steps=steps, batch_size=64
                ),
            )
            from mop.train import train

            run_dir = train(cfg, out / f"run-{axis}{v}", progress=progress)
            traj = _test_trajectories(base.test_system, p.num_test_systems, T, seed)
            r = evaluate([_learned(run_dir, "mop", "window"), make_baseline("kalman")], traj, progress)
            mse = {k: float((r[k]["e"][:, 1:] ** 2).mean()) for k in r}
            excess.append(max(mse["mop"] - mse["kalman"], 1e-12))
        slope, intercept, se = loglog_slope(values, excess)
        half = t_quantile(0.975, max(len(values) - 2, 1)) * se  # Student t, n - 2 dof
        ci = (slope - half, slope + half)
        results[axis] = {
            "values": list(values),
            "excess_mse": excess,
            "slope": slope,
            "slope_stderr": se,
            "slope_ci95": list(ci),
        }
        figs = save(
            loglog_figure(values, excess, slope, intercept, axis, f"excess risk vs {axis}"),
            out,
            f"scaling_{axis}",
        )
        sections.append(
            f"## against {axis}\n\nExcess MSE = test MSE of MOP minus the oracle KF's, over t in [1,T]; "
            "the theorem's bound predicts a slope of -1/2.\n\n"
            f"| {axis} | excess MSE |\n|---|---|\n"
            + "\n".join(f"| {v} | {e:.5f} |" for v, e in zip(values, excess, strict=True))
            + f"\n\nslope {slope:.3f} (OLS s.e. {se:.3f}, 95% t-interval [{ci[0]:.3f}, {ci[1]:.3f}], "
            f"{len(values) - 2} dof)\n\n"
            + "\n".join(f"![{f.name}]({f.name})" for f in figs if f.suffix == ".png")
        )
        claims.append(
            claim_line(
                f"excess risk decays like (M T)^(-1/2) in {axis}",
                f"fitted slope {slope:.3f} [{ci[0]:.3f}, {ci[1]:.3f}]",
                ci[0] <= -0.5 <= ci[1] if len(values) > 2 else None,
            )
        )
    summary = {"num_systems": p.num_test_systems, "horizon": 50, "predictors": {}, "scaling": results}
    return summary, sections, claims, {"grid": {"M": list(M_values), "T": list(T_values), "steps": steps}}
