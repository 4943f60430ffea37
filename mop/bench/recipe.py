"""`mop bench recipe`: the MOP/reference MSE ratio each training recipe reaches within a budget, over seeds.

Every recipe trains from scratch once per budget (default 60, 120, 180 s) and training seed (--seeds K:
train.seed = 0..K-1, default 2), then predicts the same N = 500 seeded test systems of --family (default
linear, T = the recipe's train.horizon); the score is the MOP/reference MSE ratio over t in [20, T] (the
reference: --reference, default the KF; kalman-colored, pf, ... for other families) with a paired bootstrap
95% CI over test systems (mop.metrics.mse_ratio_ci). Each row reports the mean ratio over seeds, its range
(min, max over seeds) and every seed's ratio and CI; --compare NAMES adds those predictors' ratios to the
reference (e.g. rls), so a recipe can be read against them.
Built in: "small" (PRESETS["small"], mop's CPU recipe) and "paper" (12 layers, width 256, 8 heads, AdamW
3e-4 constant, wd 0.01, clip 1, batch 64, M = 20000). A new recipe name starts from the small preset with
the cosine ending at final_lr=0 unless given (final_lr=0.1 is the preset's own schedule).

Time-limited schedule: the run's progress is p = elapsed / budget (or step / steps with --steps, which is
deterministic); lr(p) = lr * p / warmup for p < warmup, then lr (train.lr_schedule=constant) or a cosine from
lr down to final_lr * lr at p = 1 (cosine); training stops at p >= 1. The clock starts before the model and
the training data are built (the paper's M = 20000 source systems count against its budget); evaluation is
not timed. The built-in "small" takes its warm-up fraction from the preset (warmup_steps / steps) and ends the
cosine at 0.1 lr as mop.train.learning_rate does, so it is the preset's schedule stretched over the budget.

A recipe is data: a name, RunConfig overrides and three schedule knobs, e.g.
    mop bench recipe --recipe tiny base=small model.num_layers=2 model.width=64 train.lr=3e-3 warmup=0.05
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
from pathlib import Path

import torch

from mop import train as mt
from mop.config import RunConfig, SystemConfig, apply_overrides
from mop.errors import MopError
from mop.experiments import TEST_SEED_OFFSET, get_preset
from mop.experiments.analyses import FORECAST_START, horizon_errors
from mop.metrics import errors, mse_ratio_ci
from mop.models import build_model
from mop.models.predictor import LearnedPredictor
from mop.plots import save
from mop.predictors import PREDICTORS, forecast, make_predictor
from mop.progress import progress as progress_bar
from mop.systems import generator, make_family
from mop.systems.base import FAMILIES, config_class

WINDOW = (20, 51)  # t in [20, 50]


@dataclasses.dataclass(frozen=True)
class Recipe:
    """A RunConfig (base preset + key=value overrides) and its budget-fraction schedule."""

    name: str
    base: str = "small"  # preset whose model and train settings start the config
    overrides: tuple[str, ...] = ()  # RunConfig overrides, "model.num_layers=2"
    warmup: float | None = None  # warm-up fraction of the budget; None: the preset's warmup_steps / steps
    final_lr: float = 0.0  # cosine end as a fraction of train.lr
    threads: int = 0  # torch.set_num_threads; 0 keeps the default

    def config(self, family: str = "linear", seed: int | None = None) -> RunConfig:
        """The recipe's RunConfig on `family` (its default knobs), train.seed = `seed` when given."""
        p = get_preset(self.base)
        model = dataclasses.replace(p.model, context=p.train.horizon)
        train = dataclasses.replace(p.train, compile="off", device="cpu")
        first = [f"system.family={family}"] + ([] if seed is None else [f"train.seed={seed}"])
        return apply_overrides(RunConfig(SystemConfig(), model, train), first + list(self.overrides))

    def lr_factor(self, progress: float, cfg) -> float:
        """Multiplier of train.lr at budget fraction `progress` in [0, 1); cfg: the recipe's TrainConfig."""
        warmup = self.warmup if self.warmup is not None else cfg.warmup_steps / cfg.steps
        if progress < warmup:
            return max(progress / warmup, 1e-3)
        if cfg.lr_schedule == "constant":
            return 1.0
        frac = (progress - warmup) / max(1e-9, 1 - warmup)
        return self.final_lr + (1 - self.final_lr) * 0.5 * (1 + math.cos(math.pi * frac))


BUILTIN = {
    "small": Recipe("small", final_lr=0.1),  # mop.train.learning_rate: cosine down to 0.1 lr
    "paper": Recipe(
        "paper",
        base="paper",
        overrides=("train.lr=3e-4", "train.lr_schedule=constant", "train.warmup_steps=0"),
        warmup=0.0,
    ),
}


def parse_recipe(words: list[str]) -> Recipe:
    """["NAME", "key=value", ...] -> Recipe (base, warmup, final_lr, threads: recipe; others: config)."""
    if not words or "=" in words[0]:
        raise MopError("--recipe takes a NAME first, then key=value overrides")
    name, fields, overrides = words[0], {}, []
    for word in words[1:]:
        key, _, value = word.partition("=")
        if key in ("base", "warmup", "final_lr", "threads"):
            fields[key] = value if key == "base" else (int(value) if key == "threads" else float(value))
        else:
            overrides.append(word)
    start = BUILTIN.get(name, Recipe(name))
    recipe = dataclasses.replace(start, **fields, overrides=start.overrides + tuple(overrides))
    recipe.config()  # validate now, not after the first budget
    return recipe


def train_for(
    recipe: Recipe,
    seconds: float | None = None,
    steps: int | None = None,
    show: bool = False,
    family: str = "linear",
    seed: int | None = None,
):
    """Train `recipe` on `family` until `seconds` of wall clock or `steps` steps; returns (model, info)."""
    if recipe.threads:
        torch.set_num_threads(recipe.threads)
    start = time.perf_counter()
    config = mt.resolve_config(recipe.config(family, seed))
    cfg, device = config.train, torch.device("cpu")
    torch.manual_seed(cfg.seed)
    model = build_model(config.model).to(device).train()
    optimizer = mt.make_optimizer(model, cfg, device)
    loss_fn = mt.maybe_compile(mt.LossModule(model), cfg, device)
    data = mt.TrainingData(config, device)
    step, loss, ema = 0, float("nan"), None
    bar = progress_bar(steps, recipe.name, disable=not show)
    while True:
        elapsed = time.perf_counter() - start
        progress = max(elapsed / seconds if seconds else 0.0, step / steps if steps else 0.0)
        if progress >= 1 and step > 0:  # at least one step, however long the set-up took
            break
        for group in optimizer.param_groups:
            group["lr"] = cfg.lr * recipe.lr_factor(min(progress, 1.0), cfg)
        loss = float(mt.train_step(model, loss_fn, optimizer, *data.batch(), cfg, device))
        if not math.isfinite(loss):
            raise MopError(f"recipe {recipe.name}: loss became {loss} at step {step}; lower train.lr")
        ema = loss if ema is None else 0.98 * ema + 0.02 * loss
        step += 1
        bar.update(1)
        bar.set_postfix(loss=f"{ema:.4g}", lr=f"{optimizer.param_groups[0]['lr']:.2g}")
    bar.close()
    elapsed = time.perf_counter() - start
    info = {"steps": step, "seconds": elapsed, "steps_per_s": step / elapsed, "train_loss": ema}
    return model.eval(), info


class TestSet:
    """N seeded test systems of `family` (float64, T steps), the reference's and the others' errors."""

    def __init__(
        self,
        num_systems: int,
        seed: int,
        family: str = "linear",
        reference: str = "kalman",
        compare: tuple[str, ...] = (),
        horizon: int = 50,
        forecast_steps: int = 0,
    ) -> None:
        fam = make_family(config_class(family)(family=family), dtype=torch.float64)
        self.traj = fam.generate(num_systems, horizon, generator=generator(seed + TEST_SEED_OFFSET))
        self.family, self.reference, self.seed = family, reference, seed
        self.window = (WINDOW[0], horizon + 1)
        self.forecast_steps = forecast_steps
        self.e_ref = errors(make_predictor(reference).predict(self.traj), self.traj.y)
        self.others, self.k_step = {}, {}
        for name in compare:
            e = errors(make_predictor(name).predict(self.traj), self.traj.y)
            self.others[name] = self._ratio(e)[0]
        for name in (reference, *compare) if forecast_steps else ():
            self.k_step[name] = self.k_step_errors(make_predictor(name))

    def _ratio(self, e) -> tuple[float, float, float]:
        return mse_ratio_ci(e, self.e_ref, *self.window, seed=self.seed)

    def ratio(self, model) -> tuple[float, float, float]:
        return self._ratio(errors(LearnedPredictor(model).predict(self.traj), self.traj.y))

    def k_step_errors(self, predictor) -> list[float]:
        """Mean ||y_{t+k-1} - forecast|| over systems and origins t >= FORECAST_START, k = 1..forecast_steps
        (the forecast analysis's numbers)."""
        f = forecast(predictor, self.traj, self.forecast_steps)
        return horizon_errors(self.traj.y, f, FORECAST_START)


def measure(
    recipes: list[Recipe],
    budgets: list[float],
    test: TestSet,
    unit: str = "seconds",
    log=print,
    seeds: int = 2,
):
    """One row per (budget, recipe): every seed's ratio and CI, their mean and range over seeds."""
    rows = []
    for budget in budgets:
        for recipe in recipes:
            limit = {"seconds": float(budget)} if unit == "seconds" else {"steps": int(budget)}
            per_seed = []
            for seed in range(seeds):
                model, info = train_for(recipe, **limit, family=test.family, seed=seed)
                ratio, low, high = test.ratio(model)
                per_seed.append({"seed": seed, **info, "ratio": ratio, "ci_low": low, "ci_high": high})
                if test.forecast_steps:
                    per_seed[-1]["k_step"] = test.k_step_errors(LearnedPredictor(model))
            rows.append(_aggregate(recipe.name, budget, unit, per_seed))
            log(_line(rows[-1]))
    return rows


def _aggregate(name: str, budget: float, unit: str, per_seed: list[dict]) -> dict:
    """Mean over seeds of steps, seconds, loss and ratio; its range; ci_*: the union of the seeds' CIs."""
    mean = lambda key: sum(r[key] for r in per_seed) / len(per_seed)  # noqa: E731
    ratios, k_step = [r["ratio"] for r in per_seed], {}
    if "k_step" in per_seed[0]:  # --forecast: the mean over seeds of each k's error
        k_step = {"k_step": [sum(c) / len(c) for c in zip(*(r["k_step"] for r in per_seed), strict=True)]}
    return {
        "recipe": name,
        "budget": budget,
        "unit": unit,
        "steps": round(mean("steps")),
        "seconds": mean("seconds"),
        "steps_per_s": mean("steps_per_s"),
        "train_loss": mean("train_loss"),
        "ratio": mean("ratio"),
        "ratio_min": min(ratios),
        "ratio_max": max(ratios),
        "ci_low": min(r["ci_low"] for r in per_seed),
        "ci_high": max(r["ci_high"] for r in per_seed),
        "seeds": per_seed,
        **k_step,
    }


def _line(r: dict) -> str:
    budget = f"{r['budget']:g} {'s' if r['unit'] == 'seconds' else 'steps'}"
    each = ", ".join(f"{s['ratio']:.4f}" for s in r["seeds"])
    k_step = "" if "k_step" not in r else "  k-step: " + " ".join(f"{e:.4f}" for e in r["k_step"])
    return (
        f"{r['recipe']:<12} {budget:>10} {r['steps']:>7d} {r['seconds']:>7.1f} {r['steps_per_s']:>8.2f}   "
        f"{r['ratio']:.4f} [{r['ratio_min']:.4f}, {r['ratio_max']:.4f}]  CI [{r['ci_low']:.4f}, "
        f"{r['ci_high']:.4f}]  seeds: {each}{k_step}"
    )


def plot(rows: list[dict], out_dir: Path, family: str = "linear", reference: str = "kalman") -> list[Path]:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for name in dict.fromkeys(r["recipe"] for r in rows):
        rs = [r for r in rows if r["recipe"] == name]
        x, y = [r["seconds"] for r in rs], [r["ratio"] for r in rs]
        err = [[r["ratio"] - r["ratio_min"] for r in rs], [r["ratio_max"] - r["ratio"] for r in rs]]
        ax.errorbar(x, y, yerr=err, marker="o", capsize=3, label=name)
    ax.axhline(1.0, color="k", lw=0.8, ls="--")
    ax.set(yscale="log", xlabel="training wall clock (s)", ylabel=f"MOP / {reference} MSE ratio, t >= 20")
    ax.set_title(f"mop bench recipe: {family} (bars: range over seeds; threads {torch.get_num_threads()})")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, which="both")
    return save(fig, out_dir, "bench-recipe")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--budgets", type=float, nargs="+", default=[60, 120, 180], help="seconds (60 120 180)"
    )
    parser.add_argument(
        "--steps", type=int, nargs="+", default=None, help="step budgets instead of seconds (deterministic)"
    )
    parser.add_argument(
        "--recipe",
        nargs="+",
        action="append",
        metavar="NAME [KEY=VALUE ...]",
        help="a recipe: a built-in (small, paper) or a new name, then overrides (model.*, train.*, base=, "
        "warmup=, final_lr=, threads=); repeatable (default: small and paper)",
    )
    parser.add_argument("--systems", type=int, default=500, help="test systems N (500)")
    parser.add_argument("--seeds", type=int, default=2, help="training seeds 0..K-1 per recipe (2)")
    parser.add_argument("--family", default="linear", help="system family to train and test on (linear)")
    parser.add_argument("--reference", default="kalman", help="denominator of the ratio (kalman)")
    parser.add_argument(
        "--compare", nargs="*", default=[], help="more predictors whose ratio to the reference is reported"
    )
    parser.add_argument(
        "--forecast",
        type=int,
        default=0,
        metavar="K",
        help="also report the k-step forecast errors (k = 1..K) of each recipe, the reference and --compare",
    )
    parser.add_argument("--seed", type=int, default=0, help="test systems use seed + 7000001 (0)")
    parser.add_argument("--out", default="runs/bench/recipe", help="plot directory (runs/bench/recipe)")


def run(args: argparse.Namespace) -> int:
    recipes = [parse_recipe(words) for words in args.recipe] if args.recipe else list(BUILTIN.values())
    unit, budgets = ("steps", args.steps) if args.steps else ("seconds", args.budgets)
    if min(budgets) <= 0 or args.systems <= 0 or args.seeds <= 0 or args.forecast < 0:
        raise MopError("budgets, --systems and --seeds must be positive, --forecast K at least 0")
    _check_names(args)
    horizon = recipes[0].config(args.family).train.horizon
    test = TestSet(
        args.systems, args.seed, args.family, args.reference, tuple(args.compare), horizon, args.forecast
    )
    if not args.json:
        print(f"{'recipe':<12} {'budget':>10} {'steps':>7} {'wall s':>7} {'steps/s':>8}   ratio [95% CI]")
    rows = measure(recipes, budgets, test, unit, (lambda _: None) if args.json else print, args.seeds)
    paths = plot(rows, Path(args.out), args.family, args.reference)
    result = {
        "device": "cpu",
        "threads": torch.get_num_threads(),
        "family": args.family,
        "reference": args.reference,
        "seeds": args.seeds,
        "compare": test.others,
        "k_step": test.k_step,
        "num_test_systems": args.systems,
        "window": list(test.window),
        "unit": unit,
        "recipes": [dataclasses.asdict(r) for r in recipes],
        "results": rows,
        "plot": [str(p) for p in paths],
    }
    if args.json:
        print(json.dumps(result))
    else:
        for name, ratio in test.others.items():
            print(f"{name:<12} ratio to {args.reference}: {ratio:.4f}")
        for name, errs in test.k_step.items():
            print(f"{name:<12} k-step: " + " ".join(f"{e:.4f}" for e in errs))
        print(f"plot: {', '.join(result['plot'])}")
    return 0


def _check_names(args: argparse.Namespace) -> None:
    """One-line errors for an unknown family or predictor, before any training."""
    if args.family not in FAMILIES.names():
        raise MopError(f"unknown --family {args.family!r}; choose one of {', '.join(FAMILIES.names())}")
    for name in (args.reference, *args.compare):
        PREDICTORS.get(name)  # MopError "unknown predictor ...; choose one of ..."
