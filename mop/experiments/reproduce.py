"""What `mop reproduce` does, as a library call: one Reproduction (the command's arguments, checked on
construction) run by `reproduce`, which validates every experiment, runs its (experiment, seed) units
(mop.experiments.schedule) and writes the summaries over seeds and of `all`.

    reproduce(Reproduction("linear", preset="smoke", out="/tmp/linear"), report=print)

Outputs: OUT/eval.json, figures and report.md (OUT/<experiment>/ for `all`; OUT/seed-<s>/ with seeds > 1,
beside OUT/seeds.json and seeds.md); OUT/summary.md for `all`. The default OUT is runs/reproduce/PRESET
(PRESET-pretrained with pretrained=True) with the experiment's name below it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

from mop.atomic import write_json, write_text
from mop.errors import MopError
from mop.experiments import EXPERIMENTS, get_experiment
from mop.experiments.files import is_experiment_file, load_experiment
from mop.experiments.presets import default_preset
from mop.experiments.schedule import UnitSettings, run_units
from mop.experiments.seeds import lead_table, seed_summary, seeds_table
from mop.experiments.spec import Experiment
from mop.experiments.validate import validate_experiment
from mop.predictors import PREDICTORS


def optional_predictors() -> list[str]:
    """The predictors some preset leaves out (their registry metadata's skip_presets)."""
    return [name for name in PREDICTORS.names() if PREDICTORS.meta(name).get("skip_presets")]


def choices(with_: list[str], without: list[str]) -> dict[str, bool]:
    """predictor -> in (True) or out (False), from --with / --without (a name in both: MopError)."""
    both = sorted(set(with_) & set(without))
    if both:
        raise MopError(f"--with and --without both name {', '.join(both)}; give one of them")
    return {**dict.fromkeys(with_, True), **dict.fromkeys(without, False)}


@dataclasses.dataclass(frozen=True)
class Reproduction:
    """One `mop reproduce`: experiment is a registered name, "all" or an experiment file (.toml / .json).

    preset None: small with pretrained=True, else paper on a GPU and small on the CPU. seeds: train K seeds
    seed..seed+K-1 on the same test systems. with_ / without: predictors forced in / out over their
    skip_presets. jobs: worker processes (1: this process). wait: see mop.train.train.
    """

    experiment: str
    preset: str | None = None
    out: str | None = None
    runs: str | None = None
    seed: int = 0
    seeds: int = 1
    overrides: list[str] = dataclasses.field(default_factory=list)
    with_: list[str] = dataclasses.field(default_factory=list)
    without: list[str] = dataclasses.field(default_factory=list)
    pretrained: bool = False
    jobs: int = 1
    progress: bool = True
    wait: bool = True

    def __post_init__(self) -> None:
        if self.seeds < 1:
            raise MopError(f"--seeds must be at least 1, got {self.seeds}")
        if self.jobs < 1:
            raise MopError(f"--jobs must be at least 1, got {self.jobs}")
        if self.pretrained and self.seeds > 1:
            raise MopError("--seeds K trains K seeds and --pretrained trains none; use one of them")
        choices(self.with_, self.without)

    @property
    def resolved_preset(self) -> str:
        return self.preset or ("small" if self.pretrained else default_preset())

    @property
    def chosen(self) -> dict[str, bool]:
        """--with / --without; with pretrained=True the optional baselines (not shipped) are off unless
        asked for."""
        chosen = choices(self.with_, self.without)
        return {**dict.fromkeys(optional_predictors(), False), **chosen} if self.pretrained else chosen

    def root(self) -> Path:
        if self.out:
            return Path(self.out)
        suffix = "-pretrained" if self.pretrained else ""
        return Path("runs/reproduce") / f"{self.resolved_preset}{suffix}"


def experiments_named(name: str) -> list[Experiment]:
    """The experiments `name` stands for: an experiment file's, every registered one ("all"), or one."""
    if is_experiment_file(name):
        return [load_experiment(name)]
    if name == "all":
        return [get_experiment(n) for n in EXPERIMENTS.names()]
    return [get_experiment(name)]


def reproduce(r: Reproduction, report: Callable[[str], None] = print) -> Path:
    """Run the reproduction; `report` gets each line to show (a unit's report, the summaries' paths).
    Returns the output root. Every mistake in any experiment is a MopError before the first training step."""
    preset, chosen, root = r.resolved_preset, r.chosen, r.root()
    experiments = experiments_named(r.experiment)
    for exp in experiments:
        validate_experiment(exp, preset, seed=r.seed, overrides=list(r.overrides), choices=chosen)
    units = [(exp, s) for exp in experiments for s in range(r.seed, r.seed + r.seeds)]
    settings = UnitSettings(
        preset, r.seed, list(r.overrides), chosen, r.pretrained, r.wait, r.runs,
        skip_missing=r.pretrained and r.experiment == "all",
    )  # fmt: skip
    many = r.experiment == "all" or not r.out
    outs = {exp.name: root / exp.name if many else root for exp in experiments}
    spec = r.experiment if is_experiment_file(r.experiment) else None  # files reload in workers (plugins)
    done = run_units(
        units, outs, jobs=r.jobs, num_seeds=r.seeds, spec=spec, settings=settings, progress=r.progress,
        report=report,
    )  # fmt: skip
    rows = []
    for exp in experiments:
        evals = {s: result for (e, s), result in zip(units, done, strict=True) if e is exp and result}
        if evals:
            rows.append(_seed_summaries(exp, evals, outs[exp.name], r.seeds, report))
    if r.experiment == "all":
        title = f"# mop reproduce all, preset {preset}, seeds {r.seed}..{r.seed + r.seeds - 1}\n\n"
        write_text(root / "summary.md", title + lead_table(rows))
        report(f"summary: {root / 'summary.md'}")
    return root


def _seed_summaries(exp: Experiment, evals: dict[int, dict], out: Path, num_seeds: int, report) -> dict:
    """Write seeds.json / seeds.md (more than one seed); the experiment's row of the `all` summary."""
    summary = seed_summary(evals)
    if num_seeds > 1:
        write_json(out / "seeds.json", summary)
        write_text(out / "seeds.md", seeds_table(exp.name, summary))
        report(f"mop reproduce {exp.name}: {num_seeds} seeds in {out / 'seeds.md'}")
    first = next(iter(summary.values()), {})
    return {"experiment": exp.name, "best": first.get("best"), "authors": exp.authors}
