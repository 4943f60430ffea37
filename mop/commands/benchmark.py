"""`mop benchmark [NAME ...] [--data-dir DIR] [--out OUT] [--budget MINUTES]`: the system-identification
benchmarks' official protocol (mop.benchmarks) for mop's fitted ARX and N4SID, MOP trained on the
estimation part (the records recipe within --budget), a shipped model in context (pretrained:NAME) or
fine-tuned on the estimation part (finetune:NAME), or the same on a user's own records with
`--est EST.csv --test TEST.csv [--init-window n]`.

Writes OUT/results.json ({benchmark: {test: {predictor: {"rmse", "units", "diverged_at"}}}}), OUT/report.md
(the table beside the published baselines, times, seeds, warnings), per test a figure (OUT/BENCH/TEST.png)
and every predictor's simulation beside the measured output (OUT/BENCH/TEST_PREDICTOR.csv).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from mop.atomic import atomic_path, write_json
from mop.benchmarks import BENCHMARKS, Split, load_benchmark, present
from mop.benchmarks.protocol import (
    CITATION,
    FEATURE,
    NETWORK,
    PUBLISHED,
    STATE_OF_THE_ART,
    TestScore,
    run_test,
    score_test,
    test_figure,
)
from mop.commands.predict import write_simulation
from mop.config import parse_overrides
from mop.errors import MopError
from mop.estimators import Learned
from mop.identify import fit, is_fitted
from mop.identify import load as load_fitted
from mop.identify.narx_model import KIND as FEATURE_KIND
from mop.identify.select import POLE_RADIUS
from mop.incontext import reading_line, simulate_with_context
from mop.models.feature_input import FEATURE_DIR
from mop.peers.narx import NarxPredictor, fit_narx, frols_class, narx_line
from mop.peers.subnet import SubnetPredictor, deepsi, fit_subnet, subnet_line
from mop.pretrained import dimensions, fitting_hint
from mop.recipe.budget import DEFAULT_BUDGET_MINUTES, budget_line, check_budget
from mop.recipe.records import feature_line
from mop.recipe.selection import feature_alone, kept_model, selection_line, training_time
from mop.record import as_pairs, read_records
from mop.runs import load_config, load_predictor, with_reading
from mop.simulators import SimulatorConfig, fit_simulator, simulator_line

PREDICTORS = (
    "arx",
    "n4sid",
    "mop",
    "lru",
    "narx",
    "subnet",
)  # and pretrained:NAME, a shipped model in context (mop.incontext),
# and finetune:NAME, that model fine-tuned on the estimation part (`mop train --data --init pretrained:NAME`)
SHIPPED_KINDS = ("pretrained:", "finetune:")
NARX = NarxPredictor.name
SUBNET = SubnetPredictor.name


def shipped_name(predictor: str) -> str:
    """pretrained:NAME for a predictor pretrained:NAME or finetune:NAME (the shipped model it reads)."""
    return predictor.replace("finetune:", "pretrained:", 1)


EXAMPLES = """
benchmarks: silverbox, f16 (Acceleration1, the official form), f16-3 (all three accelerations),
cascaded-tanks, emps, wiener-hammerstein, ced.
examples:
  mop benchmark silverbox --data-dir ~/benchmarks          # folder laid out as silverbox/SNLS80mV.csv
  mop benchmark --data-dir ~/benchmarks                    # every benchmark whose files are there
  mop benchmark silverbox f16 --budget 10 --out runs/bench
  mop benchmark --est est.csv --test val.csv --init-window 50   # your own records, the same protocol
  mop benchmark silverbox --predictors arx,n4sid           # the fitted linear models only (fast)
  mop benchmark silverbox --predictors arx,pretrained:lti-siso   # a shipped class model in context
  mop benchmark f16 --predictors mop,finetune:duffing-records    # fine-tuned on the estimation part
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.epilog = EXAMPLES
    parser.add_argument(
        "names", nargs="*", metavar="NAME", help="benchmarks (default: all whose files are there)"
    )
    parser.add_argument(
        "--data-dir", default=None, help="folder of the benchmark files (or $MOP_BENCHMARK_DATA)"
    )
    parser.add_argument("--out", default="runs/benchmark", help="output folder (runs/benchmark)")
    parser.add_argument(
        "--budget", default=None, metavar="MINUTES", help="MOP's training budget per benchmark (default 5)"
    )
    parser.add_argument("--seed", type=int, default=0, help="MOP's training seed (0)")
    parser.add_argument(
        "--train",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a config key for MOP's training, as `mop train --data` takes it (repeatable), e.g. "
        "train.simulate_after=10",
    )
    parser.add_argument(
        "--predictors",
        default="arx,n4sid,mop",
        help="comma-separated: arx, n4sid, mop, lru (a deep-LRU simulator trained on its simulation error, "
        "mop.simulators), narx (sysidentpy's FROLS polynomial NARX, least squares, an optional extra: "
        "pip install --no-deps sysidentpy==0.9.0), subnet (deepSI's SUBNET, its defaults, trained within "
        "--budget, an optional extra), pretrained:NAME (in context), finetune:NAME "
        "(pretrained:NAME fine-tuned on the "
        "estimation part within --budget); default arx,n4sid,mop",
    )
    parser.add_argument(
        "--est", default=None, help="your estimation record (.csv / .npz) instead of a benchmark"
    )
    parser.add_argument("--test", action="append", default=None, help="your test record (repeatable)")
    parser.add_argument("--init-window", type=int, default=50, help="with --test: measured outputs n (50)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def _splits(args: argparse.Namespace) -> list[Split]:
    """Every split to run, loaded (and so checked) before any fitting."""
    if args.est is not None or args.test is not None:
        if args.names:
            raise MopError("give benchmark names or --est/--test, not both")
        if args.est is None or not args.test:
            raise MopError("your own records need both --est EST and --test TEST")
        estimation = read_records(args.est)
        tests = []
        for path in args.test:
            for r in read_records(path):
                if args.init_window < 1 or args.init_window >= len(r):
                    raise MopError(
                        f"--init-window {args.init_window} must be in [1, {len(r) - 1}] for {path}"
                    )
                tests.append(dataclasses.replace(r, init_window=args.init_window))
        widths = {(r.num_outputs, r.num_inputs) for r in estimation + tests}
        if len(widths) > 1:
            raise MopError(f"--est and --test differ in their output / input widths {sorted(widths)}")
        if tests[0].num_inputs == 0:
            raise MopError("the records have no input column u0: a simulation needs the inputs")
        return [Split(Path(args.est).stem, estimation, tests, "")]
    names = args.names or present(args.data_dir)
    if not names:
        raise MopError(
            "no benchmark named and none found; give NAME (silverbox, f16, ...) with --data-dir DIR, "
            "or set $MOP_BENCHMARK_DATA"
        )
    for name in names:
        BENCHMARKS.get(name)  # an unknown name is one line, before any file is read
    return [load_benchmark(name, args.data_dir) for name in names]


class InContextModel:
    """A shipped class model that reads the estimation part's last record before each test (mop.incontext),
    with no training; run_test calls its simulate like any predictor's."""

    def __init__(self, model, estimation) -> None:
        self.model, self.estimation, self.name = model, estimation, model.name

    def run(self, test) -> tuple[TestScore, str]:
        """The test's score and how the estimation part was read (mop.incontext.reading_line)."""
        n = max(test.init_window, 1)
        done = simulate_with_context(self.model, test, n, self.estimation)
        return score_test(test, done.simulation), reading_line(done)


def check_reads(name: str, model, split: Split) -> None:
    """One-line MopError, before any fit, unless the shipped model reads the split's records: the same
    number of inputs and of outputs, or in context (pretrained:NAME) one output (read one output at a time,
    mop.incontext.by_channel); a fine-tune (finetune:NAME) trains on the records as they are."""
    m_model, k_model = dimensions(dataclasses.asdict(model.cfg))
    m, k = split.tests[0].num_outputs, split.tests[0].num_inputs
    widths = (m,) if name.startswith("finetune:") else (1, m)
    if k != k_model or m_model not in widths:
        raise MopError(
            f"{name} reads {m_model} output(s) and {k_model} input(s), {split.name} has {m} and {k}; "
            + fitting_hint(m, k)
        )


def _fitted(kind: str, split: Split, warnings: list[str]):
    fitted = fit(kind, as_pairs(split.estimation), source=split.name)
    radius = fitted.info.get(POLE_RADIUS, 0.0)
    if radius >= 1:
        warnings.append(
            f"{split.name}: the fitted {kind.upper()} {dict(fitted.orders)} is unstable (largest pole "
            f"modulus {radius:.4g}); its simulations may diverge"
        )
    return fitted


def alone(name: str, run_dir: Path, selection: dict) -> dict:
    """{f"{name}:network": the run's network as trained, in its reading of the lowest check score} where its
    held-out check kept a least-squares model, and {f"{name}:feature": the recipe's least-squares feature
    as the check scored it} where it was a candidate and was not kept: each then simulates the tests beside
    what the run keeps, so a table shows the network alone, the feature alone and what the check chose."""
    out = {}
    if selection["kept"] != "network":  # as trained (gain 1), in the reading the check scored lowest
        network = load_predictor(run_dir)
        own = {r: s[selection["gains"].index(1.0)]["score"] for r, s in selection["network"].items()}
        with_reading(network, min(own, key=own.get))
        out[f"{name}:{NETWORK}"] = network
    if selection["kept"] != FEATURE_KIND and is_fitted(run_dir / FEATURE_DIR):
        out[f"{name}:{FEATURE}"] = load_fitted(run_dir / FEATURE_DIR)
    return out


def _write_simulation(path: Path, test, score: TestScore) -> None:
    """The simulation beside the measured output, one row per scored step, in `mop predict --simulate`'s
    layout (trajectory, t, y0.., ysim0..)."""
    write_simulation(path, [test.name], [score.simulation], max(test.init_window, 1), [test.y])


def leaks(split: Split) -> list[str]:
    """A warning for each test record that is (or holds) an estimation record: the same samples scored as
    a test say nothing about a model fitted on them."""
    out = []
    for test in split.tests:
        for est in split.estimation:
            if est.num_outputs == test.num_outputs and contains(est, test):
                out.append(
                    f"test {test.name!r} holds the estimation record {est.name!r}: its score measures the "
                    "fit on the data it was fitted on, not a prediction; give a test record the fit never saw"
                )
                break
    return out


def contains(a, b) -> bool:
    """Whether records a and b share a stretch of 20 samples (or all of the shorter): the same outputs and
    inputs, bit for bit, at some offset."""
    short, long_ = (a, b) if len(a) <= len(b) else (b, a)
    n = min(20, len(short))
    key = np.concatenate([np.nan_to_num(short.y[:n]), short.u[:n] if short.u is not None else short.y[:0]], 1)
    whole = np.concatenate([np.nan_to_num(long_.y), long_.u if long_.u is not None else long_.y[:, :0]], 1)
    first = np.flatnonzero((whole == key[0]).all(axis=1))
    return any(i + n <= len(whole) and np.array_equal(whole[i : i + n], key) for i in first[:1000])


def _run_split(split: Split, args, predictors: list[str], budget: float, out: Path, bar) -> dict:
    folder = out / split.name
    folder.mkdir(parents=True, exist_ok=True)
    warnings: list[str] = leaks(split)
    for w in warnings:
        print(f"warning: {split.name}: {w}")
    notes: list[str] = []  # what each predictor turned out to be (MOP's feature and held-out choice)
    models, seconds = {}, {}
    for name in predictors:
        bar.set_postfix_str(f"{split.name}: fitting {name}")
        start = time.perf_counter()
        if name.startswith("pretrained:"):
            models[name] = InContextModel(load_predictor(name), split.estimation)
        elif name == "mop" or name.startswith("finetune:"):
            init = None if name == "mop" else shipped_name(name)
            learned = Learned(
                budget_minutes=budget,
                init=init,
                out_dir=folder / name.replace(":", "-"),
                **{"train.seed": args.seed, **parse_overrides(args.train)},
            )
            models[name] = learned.fit(with_init_window(split)).predictor_
            kept = kept_model(getattr(learned, "selection_", None) or {})
            if kept != "network":
                warnings.append(
                    f"{split.name}: {name} did not beat its fitted least-squares models on held-out data and "
                    f"is the fitted {kept}"
                )
            config = load_config(learned.run_dir_)
            notes.append(f"{name}: {feature_line(config) or 'no input feature'}")
            took = training_time(learned.run_dir_)
            trained = budget_line(config.train.steps, budget, config.train.horizon)
            size = f"{config.model.arch} {config.model.num_layers} x {config.model.width}"
            notes.append(
                f"{name}: trained {size}, {trained}{f'; its log: {took} on this machine' if took else ''}"
            )
            if getattr(learned, "selection_", None):
                feature = feature_alone(config)
                notes.append(f"{name}: {selection_line(learned.selection_, feature)}")
                models.update(alone(name, learned.run_dir_, learned.selection_))
        elif name == NARX:
            models[name] = fit_narx(split.estimation)
            notes.append(f"{name}: {narx_line(models[name])}")
        elif name == SUBNET:
            n = min(max(t.init_window, 1) for t in split.tests)
            models[name] = fit_subnet(split.estimation, n, seed=args.seed, minutes=budget)
            notes.append(f"{name}: {subnet_line(models[name])}")
        elif name == "lru":
            cfg = SimulatorConfig(init_window=min(max(t.init_window, 1) for t in split.tests), seed=args.seed)
            models[name] = fit_simulator(split.estimation, cfg)
            notes.append(f"lru: {simulator_line(models[name])}")
        else:
            models[name] = _fitted(name, split, warnings)
        seconds[name] = time.perf_counter() - start
        bar.update(1)
    results: dict = {}
    for test in split.tests:
        scores = {}
        for name, model in models.items():
            bar.set_postfix_str(f"{split.name}: simulating {test.name} with {name}")
            if isinstance(model, InContextModel):
                score, reading = model.run(test)
                notes.append(f"{name} on {test.name}: the estimation part {reading}")
            else:
                score = run_test(model, test)
            scores[name] = score
            _write_simulation(folder / f"{test.name}_{name.replace(':', '-')}.csv", test, score)
            if score.diverged_at is not None:
                warnings.append(
                    f"{split.name} {test.name}: {name}'s simulation diverged at step {score.diverged_at}"
                )
            bar.update(1)
        shown, scale = shown_units(split)
        test_figure(test, {k: s.simulation for k, s in scores.items()}, shown, folder, test.name, scale)
        results[test.name] = {
            k: {
                "rmse": s.rmse,
                "units": split.units,
                "n": max(test.init_window, 1),
                "diverged_at": s.diverged_at,
            }
            for k, s in scores.items()
        }
    return {
        "results": results,
        "seconds": seconds,
        "warnings": warnings,
        "notes": notes,
        "shown": shown_units(split),
    }


def with_init_window(split: Split) -> list:
    """The estimation records with the tests' initialization window n (the smallest of the tests'), so a
    records run's held-out check simulates after as many measured outputs as the tests give
    (mop.recipe.selection.init_window)."""
    n = min(max(t.init_window, 1) for t in split.tests)
    return [dataclasses.replace(r, init_window=n) for r in split.estimation]


def shown_units(split: Split) -> tuple[str, float]:
    """(units, scale) of a split's tables and figures: the field's (mV, mm) for a benchmark, the outputs'
    own for a user's records ("" where unknown)."""
    if split.name in BENCHMARKS.names():
        return BENCHMARKS.get(split.name).shown_units()
    return split.units, 1.0


def _fmt(x: float, scale: float) -> str:
    return "diverged" if math.isinf(x) else f"{x * scale:.4g}"


def _report(runs: dict, args, budget: float) -> str:
    own = args.est is not None
    if own:
        lines = ["# Your records: free-run simulation RMSE on the test records", ""]
        lines.append(
            f"Protocol: fitted on {args.est} only; on each test record the first {args.init_window} measured "
            "outputs initialize and the rest is simulated from the input alone; RMSE of y[n:] in the "
            "outputs' units."
        )
    else:
        lines = ["# Benchmarks: free-run simulation RMSE on the official tests", ""]
        lines.append(
            "Protocol (the official loader's): fitted on the estimation part only; on each test the first n "
            "measured outputs initialize (n per test below) and the rest is simulated from the input alone; "
            "RMSE of y[n:]. The F-16 has no official n; 50 is mop's choice."
        )
    if "mop" in args.predictors.split(","):
        lines.append(f"MOP: the records recipe within a budget of {budget:g} min, seed {args.seed}.")
    if "pretrained:" in args.predictors:
        lines.append(
            "pretrained:NAME: a shipped class model, the estimation part as its context, no training."
        )
    if "finetune:" in args.predictors:
        lines.append(
            f"finetune:NAME: pretrained:NAME fine-tuned on the estimation part (`mop train --data --init`) "
            f"within a budget of {budget:g} min, seed {args.seed}."
        )
    lines.append("")
    for bench, run in runs.items():
        shown, scale = run["shown"]
        published = PUBLISHED.get(bench, {})
        best = STATE_OF_THE_ART.get(bench, {})
        predictors = list(next(iter(run["results"].values())))
        pub_names = sorted({k for t in published.values() for k in t})
        extra = [f"{p} (published)" for p in pub_names] + (["state of the art"] if best else [])
        lines += [f"## {bench}" + (f" ({shown})" if shown else ""), ""]
        lines.append("| test | n | " + " | ".join([*predictors, *extra]) + " |")
        lines.append("|---" * (2 + len(predictors) + len(extra)) + "|")
        for test, scores in run["results"].items():
            n = next(iter(scores.values()))["n"]
            cells = [_fmt(scores[p]["rmse"], scale) for p in predictors]
            known = published.get(test, {})
            cells += [_fmt(known[p], scale) if p in known else "-" for p in pub_names]
            if best:
                cells.append(_fmt(best[test][0], scale) if test in best else "-")
            lines.append(f"| {test} | {n} | " + " | ".join(cells) + " |")
        lines.append("")
        lines.append(
            "Fitting / training time: " + ", ".join(f"{k} {v:.0f} s" for k, v in run["seconds"].items())
        )
        for note in run.get("notes", []):
            lines.append(f"- {note}")
        for w in run["warnings"]:
            lines.append(f"- warning: {w}")
        for test, (value, method) in best.items():
            lines.append(f"- state of the art on {test}: {_fmt(value, scale)} {shown}, {method}")
        lines.append("")
        for test in run["results"]:
            lines.append(f"![{bench} {test}]({bench}/{test}.png)")
        lines.append("")
    if any(b in PUBLISHED for b in runs):
        lines += [f"Published baselines: {CITATION}.", ""]
    return "\n".join(lines)


PROVENANCE = "provenance"  # results.json's key of what produced it (never a benchmark's name)


def provenance(argv: list[str], program: str = "mop") -> dict[str, str]:
    """What produced a results file: the command line (`program` and argv: a script passes its own path),
    mop's commit (where run from a git checkout), the machine and the date, so a results page can name
    them."""
    import platform
    import shlex
    import subprocess
    from datetime import datetime, timezone

    try:
        commit = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"],
            cwd=Path(__file__).resolve().parent,
            capture_output=True,
            text=True,
            timeout=10,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        commit = ""
    return {
        "command": f"{program} {shlex.join(argv)}",
        "commit": commit or "unknown",
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, {platform.system()}",
        "date": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
    }


def provenance_line(record: dict[str, str]) -> str:
    """A provenance (see `provenance`) as one markdown line, for a report a script writes beside its table."""
    return (
        f"Written by `{record['command']}` at commit {record['commit']} on {record['machine']}, "
        f"{record['date']}."
    )


def report_head(title: str, program: str, description: str, columns: list[str]) -> list[str]:
    """The first lines of a script's markdown report: the title, the provenance line of this run of
    `program` (sys.argv's arguments), the description and the table's header for `columns`."""
    return [
        f"# {title}",
        "",
        provenance_line(provenance(sys.argv[1:], program=program)),
        "",
        description,
        "",
        "| " + " | ".join(columns) + " |",
        "|---" * len(columns) + "|",
    ]


def run(args: argparse.Namespace) -> int:
    predictors = [p.strip() for p in args.predictors.split(",") if p.strip()]
    unknown = [p for p in predictors if p not in PREDICTORS and not p.startswith(SHIPPED_KINDS)]
    if unknown or not predictors:
        raise MopError(
            f"--predictors: unknown {', '.join(unknown) or '(none)'}; choose from {', '.join(PREDICTORS)} "
            "or pretrained:NAME, finetune:NAME (mop pretrained list)"
        )
    shipped = {  # an unknown name is one line
        n: load_predictor(shipped_name(n)) for n in predictors if n.startswith(SHIPPED_KINDS)
    }
    budget = DEFAULT_BUDGET_MINUTES if args.budget is None else check_budget(args.budget)
    parse_overrides(args.train)  # a malformed key=value is refused before any work
    if NARX in predictors:
        frols_class()  # not installed: one line before any work
    if SUBNET in predictors:
        deepsi()
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise MopError(f"--out {out} is a file; give a folder")
    splits = _splits(args)
    for name, model in shipped.items():
        for split in splits:
            check_reads(name, model, split)
    total = sum(len(predictors) * (1 + len(s.tests)) for s in splits)
    runs = {}
    with tqdm(total=total, disable=args.quiet, desc="benchmark", unit="task") as bar:
        for split in splits:
            runs[split.name] = _run_split(split, args, predictors, budget, out, bar)
    write_json(
        out / "results.json",
        {**{b: r["results"] for b, r in runs.items()}, PROVENANCE: provenance(getattr(args, "_argv", []))},
    )
    report = _report(runs, args, budget)
    with atomic_path(out / "report.md") as tmp:
        Path(tmp).write_text(report)
    print(report)
    print(f"wrote {out / 'results.json'} and {out / 'report.md'}")
    return 0
