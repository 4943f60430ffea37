"""Never worse than the fitted least-squares models: the choice a records run makes after training.

After a records-recipe run has trained, the candidates are its network, in each of its readings (readings:
a network trained for simulation reads its simulated outputs as missing, as it trained, or its predictions
fed back), for a transformer reading a feature with the correction at each gain of mop.recipe.shrink.GAINS
(1: as trained; 0: its in-context feature alone; trained for simulation at 0 and 1 only: gains_of), and
the linear models `mop fit arx` and `mop fit n4sid` choose on the same training part (LINEAR); for a
network that reads no feature (the records recipe's deep LRU) also the recipe's least-squares feature
fitted on that part as a model of its own where it is not that ARX (a cubic NARX or a longer ARX:
mop.identify.narx_model, FEATURE).
Each simulates from the inputs alone, after n measured outputs (the records' initialization
window, Record.init_window, as a benchmark's test is simulated, where they give one, else INIT_WINDOW):
- the held-out data (held_out_stretches: the last 10% of a record after the n measured steps before it, or
  the held-out trajectories, or --val): unseen, but on a short record a hundred steps or so;
- a long free run (long_run_stretches: the last LONG_RUN steps of the records, the held-out part included):
  as long a simulation as a test of the record's length asks, where a correction that drifts or diverges
  after a few hundred steps shows.
A candidate's score is the mean of the two RMSEs (inf where either diverged: mop.records.divergence_step),
and the lowest wins. On the real cascaded tanks (1024 samples, a test simulated after 5) the held-out tail
alone kept, on one training seed in three, a network that then diverged or doubled the ARX's error on the
test; the long run ranked every candidate of those runs as the test did.
selection.json in the run directory holds every score and the one kept:
- the network, in its reading at its gain: the reading becomes the run's forecast_mode
  (mop.runs.load_predictor reads it), a gain below 1 is written into the run's weights;
- a least-squares model otherwise: the run directory also holds it (fitted.json): the ARX or N4SID refitted
  on the whole estimation record, exactly what `mop fit KIND FILE` writes, or the feature as scored; `mop
  predict RUN`, `mop.load(RUN)` load it (they read a directory with fitted.json as a fitted model),
  and mop.runs.load_predictor(RUN) still loads the network;
- the feature, where it was a candidate, is kept loadable as scored in RUN/feature (FEATURE_DIR, a fitted
  model's directory), so what each candidate simulates can be measured on a test (`mop benchmark` does),
so a user never gets a run that simulates its record worse than the better linear model would have.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from mop.atomic import write_json
from mop.checkpoint import save_model
from mop.config import RunConfig
from mop.errors import MopError
from mop.identify.arx import ARX
from mop.identify.n4sid import N4SID
from mop.identify.narx_model import KIND as FEATURE
from mop.identify.select import fit
from mop.identify.store import FILE as FITTED_FILE
from mop.identify.store import load as load_fitted
from mop.models import reads_features
from mop.models.feature_input import FEATURE_DIR
from mop.recipe.records import fitted_feature
from mop.recipe.shrink import GAINS, gain_scores, scale_correction
from mop.records import divergence_step, simulate_all
from mop.runs import SELECTION_FILE, load_predictor, with_reading
from mop.train.estimate import duration
from mop.train.records import RecordedData

FORMAT = 4  # of SELECTION_FILE: a run holding an older one chooses again
INIT_WINDOW = 50  # measured outputs a held-out simulation starts from where the records give none
LONG_RUN = 2000  # steps of the long free run (long_run_stretches)
LINEAR = (ARX.kind, N4SID.kind)  # the fitted linear models the network must beat, preferred in this order
NAMES = {ARX.kind: "ARX", N4SID.kind: "N4SID", FEATURE: "least-squares feature, NARX"}


def simulation_rmse(predictor, data: list[tuple[np.ndarray, np.ndarray]], init: int) -> float:
    """RMSE of y[init:] simulated from y[:init] and the inputs, pooled over the records; inf where the
    simulation turned non-finite (a diverged run is not scored over its finite steps)."""
    return stretches_rmse(predictor, [(y, u, init) for y, u in data])


def stretches_rmse(predictor, stretches: list[tuple[np.ndarray, np.ndarray, int]]) -> float:
    """simulation_rmse of stretches (y, u, init), each simulated after its own first `init` outputs."""
    errors = []
    for y, u, init in stretches:
        sim = simulate_all(predictor, [(y, u)], init)[0]
        if divergence_step(y, sim) is not None:
            return math.inf
        errors.append(y[init:] - sim)
    return float(np.sqrt(np.nanmean(np.concatenate(errors) ** 2)))


def init_window(record: RecordedData) -> int:
    """n, the measured outputs a held-out simulation starts from: the largest initialization window the
    given records name (Record.init_window, e.g. a benchmark's n), else INIT_WINDOW."""
    named = [r.init_window for r in record.given.records if r.init_window > 0]
    return max(named) if named else INIT_WINDOW


def held_out_stretches(
    record: RecordedData, n: int | None = None
) -> list[tuple[np.ndarray, np.ndarray, int]]:
    """(y, u, init) of each held-out stretch: where one record is split in time, its held-out tail after the
    n (init_window) measured steps before it (as a test record is simulated after its initialisation
    window), so every held-out step is scored; held-out records (--val, or whole trajectories) from their
    own first min(n, L/2) outputs."""
    n = init_window(record) if n is None else n
    m = record.output_dim
    pairs = lambda a: (a[:, :m], a[:, m:])  # noqa: E731
    if record.split == "time":
        stretches = []
        for train, val in zip(record.train_parts, record.val_parts, strict=True):
            init = min(n, len(train))
            stretches.append((*pairs(np.concatenate([train[len(train) - init :], val])), init))
        return stretches
    init = max(1, min(n, min(len(a) for a in record.val_parts) // 2))
    return [(*pairs(a), init) for a in record.val_parts]


def long_run_stretches(record: RecordedData, n: int) -> list[tuple[np.ndarray, np.ndarray, int]]:
    """(y, u, init) of the long free run: the last LONG_RUN steps of the given records (the whole of a
    shorter record; records taken from the last until LONG_RUN steps are reached), each simulated from its
    own first min(n, L/2) outputs to its end, its held-out part included: as long a free run as a test of
    the record's length (capped, so a long record's check stays quick)."""
    stretches, total = [], 0
    for r in reversed(record.given.records):
        take = min(len(r.y), LONG_RUN - total)
        u = r.u if r.u is not None else np.zeros((len(r.y), 0))
        stretches.append((r.y[-take:], u[-take:], max(1, min(n, take // 2))))
        total += take
        if total >= LONG_RUN:
            break
    return stretches


def _gains_apply(predictor) -> bool:
    """Whether the network's correction can be scaled (mop.recipe.shrink): a transformer with the mean
    read-out reading a feature, whose gain 0 is that feature alone."""
    cfg = getattr(getattr(predictor, "model", None), "cfg", None)
    return cfg is not None and getattr(cfg, "rls_order", 0) > 0 and getattr(cfg, "readout", "") == "mean"


def gains_of(predictor) -> tuple[float, ...]:
    """The gains the check weighs the network's correction at: every gain of mop.recipe.shrink.GAINS for a
    transformer trained one step ahead (its correction kept gain 0.5 or 0.75 in 10 of the 28 checks of
    the results pages' recorded plants, each below both ends); 0 (its feature alone) and 1 (as trained)
    for one trained for simulation (trained_for_simulation: on the real cascaded tanks, seeds 0-2, and the
    F-16 its checks kept gain 1, 1, 1 and 0, the gains between never lowest); 1 alone where the correction
    cannot be scaled."""
    if not _gains_apply(predictor):
        return (1.0,)
    return (0.0, 1.0) if trained_for_simulation(predictor.model.cfg) else GAINS


def trained_for_simulation(cfg) -> bool:
    """Whether the network trained for simulation with an observation mask (train.simulate_after): it
    reads its simulated outputs as missing (model.forecast_mode "gap")."""
    return bool(cfg.observation_mask) and cfg.forecast_mode == "gap"


def readings(cfg) -> tuple[str, ...]:
    """How the network may simulate (model.forecast_mode): a network trained for simulation
    (trained_for_simulation) reads the simulated outputs as missing ("gap", as it trained) or its own
    predictions fed back as measured ("rollout", its one-step reading, at gain 0 its feature's own free
    run); any other network its own forecast_mode."""
    if trained_for_simulation(cfg):
        return ("gap", "rollout")
    return (cfg.forecast_mode,)


def _fit_linear(train: list, source: str) -> dict:
    """{kind: the fitted model} of LINEAR on the training part; a kind that cannot be fitted there (a
    record too short for N4SID's Hankel matrices) is left out."""
    fitted = {}
    for kind in LINEAR:
        try:
            fitted[kind] = fit(kind, train, source=source)
        except MopError:
            if kind == LINEAR[0]:
                raise
    return fitted


def _feature_model(config: RunConfig, record: RecordedData, run_dir: Path) -> dict:
    """{FEATURE: the records recipe's least-squares feature fitted on the training part} for a network that
    reads no feature (model.arch=deep-lru, gru), where that feature is not the fitted ARX: a cubic NARX or a
    longer ARX (mop.recipe.records.feature_orders; mop.identify.narx_model); for a network that reads its
    run (data.feature_input = "free-run"), the one it read, whatever its orders (RUN/feature). A
    transformer reading one has it already, as its correction at gain 0. {} otherwise."""
    if config.data.reads_feature_run:
        return {FEATURE: load_fitted(run_dir / FEATURE_DIR)}
    if reads_features(config.model.arch):
        return {}
    feature, more = fitted_feature(record)
    return {FEATURE: feature} if more else {}


def _refit(kind: str, model, record: RecordedData, source: str):
    """The kept least-squares model as the run holds it: `mop fit KIND`'s model refitted on the whole
    estimation record (its orders chosen again there), or the feature as the check scored it (fitted on
    the training part: the coefficients a transformer reading it starts from)."""
    return model if kind == FEATURE else fit(kind, list(record.given.records), source=source)


def check_scores(predictor, record: RecordedData) -> dict[str, float]:
    """_scores of a predictor on the record's held-out and long-run stretches, as the check scores each
    candidate (init_window measured outputs before each)."""
    n = init_window(record)
    return _scores(predictor, held_out_stretches(record, n), long_run_stretches(record, n))


def _scores(predictor, held_out: list, long_run: list) -> dict[str, float]:
    """{"held_out", "long_run", "score"}: the two simulations' RMSE and their mean (inf where either
    diverged)."""
    a, b = stretches_rmse(predictor, held_out), stretches_rmse(predictor, long_run)
    return {"held_out": a, "long_run": b, "score": (a + b) / 2}


def select_against_linear(run_dir: str | Path, config: RunConfig, record: RecordedData) -> dict:
    """Choose what the finished run in `run_dir` predicts with (see the module docstring): the network in
    each of its readings with its correction at each gain of mop.recipe.shrink.GAINS, or a linear model of
    LINEAR fitted on the training part, by the mean of two free-run RMSEs after n measured outputs
    (init_window): of the held-out data (held_out_stretches) and of the long run (long_run_stretches). On a
    tie the network (as it trained, at the larger gain), then the ARX, is kept. Writes SELECTION_FILE; the
    kept reading is the run's forecast_mode from then on (mop.runs.load_predictor reads it), a gain below 1
    is written into the run's model.safetensors, and where a linear model wins the run also holds it
    refitted on the whole record (fitted.json, as `mop fit KIND` writes it). A run that already holds
    SELECTION_FILE keeps its choice.
    record: config.data's records in memory, split as it asks (mop.train.records.RecordedData)."""
    run_dir = Path(run_dir)
    done = run_dir / SELECTION_FILE
    if done.is_file():
        previous = json.loads(done.read_text())
        if previous.get("format") == FORMAT:
            return previous
    m = record.output_dim
    train = [(a[:, :m], a[:, m:]) for a in record.train_parts]
    n = init_window(record)
    held_out, long_run = held_out_stretches(record, n), long_run_stretches(record, n)
    linear = {**_fit_linear(train, config.data.path), **_feature_model(config, record, run_dir)}
    network = load_predictor(run_dir)
    network.model.eval()
    gains = gains_of(network)
    network_scores: dict[str, list[dict[str, float]]] = {}
    for reading in readings(network.model.cfg):
        with_reading(network, reading)
        score = lambda: _scores(network, held_out, long_run)  # noqa: E731
        network_scores[reading] = gain_scores(network.model, score, gains) if len(gains) > 1 else [score()]
    with_reading(network, config.model.forecast_mode)
    linear_scores = {kind: _scores(model, held_out, long_run) for kind, model in linear.items()}
    # candidates in order of preference on a tie: the network as it trained at the larger gain, then
    # its other readings, then LINEAR's order
    candidates = [
        (reading, g, scores[gains.index(g)]["score"])
        for reading, scores in network_scores.items()
        for g in sorted(gains, reverse=True)
    ]
    candidates += [(kind, None, linear_scores[kind]["score"]) for kind in linear]
    best = min(range(len(candidates)), key=lambda i: (candidates[i][2], i))
    name, gain, _ = candidates[best]
    kept, reading = ("network", name) if name in network_scores else (name, None)
    if FEATURE in linear:  # the feature alone stays loadable beside the run: `mop predict RUN/feature`
        (run_dir / FEATURE_DIR).mkdir(exist_ok=True)
        write_json(run_dir / FEATURE_DIR / FITTED_FILE, {"format": 1, **linear[FEATURE].to_json()})
    fitted = run_dir / FITTED_FILE
    if kept != "network":
        whole = _refit(kept, linear[kept], record, config.data.path)
        write_json(fitted, {"format": 1, **whole.to_json()})
    else:
        fitted.unlink(missing_ok=True)
        if gain != 1.0:  # the scaled read-out becomes the run's weights
            scale_correction(network.model, gain)
            save_model(run_dir / "model.safetensors", network.model)
    own = network_scores[config.model.forecast_mode][gains.index(1.0)]
    result = {
        "format": FORMAT,
        "held_out_steps": int(sum(len(y) - init for y, _, init in held_out)),
        "long_run_steps": int(sum(len(y) - init for y, _, init in long_run)),
        "init": int(n),
        "gains": list(gains),
        "network": network_scores,
        "network_rmse": own["score"],
        "linear_models": linear_scores,
        "linear_orders": {kind: dict(model.orders) for kind, model in linear.items()},
        "kept": kept,
        "reading": reading,
        "gain": gain if kept == "network" else None,
    }
    write_json(done, result)
    return result


def feature_alone(config: RunConfig) -> str:
    """What a run's network reads as its feature, in words: what its correction at gain 0 leaves."""
    m = config.model
    kind = f"ARX({m.rls_order}, {m.arx_order})" if m.arx_order else f"RLS-AR({m.rls_order})"
    if m.rls_cubes:
        kind = f"cubic NARX ({kind} with the cubes of its first {m.rls_cubes} output lags)"
    offset = " with an intercept" if m.rls_offset else ""
    if m.rls_fixed:
        how = "fixed at its least-squares fit on the training part"
    elif m.rls_prior != "none":
        how = "started from its least-squares fit on the training part, updated on the outputs it reads"
    else:
        how = "identified in context from the outputs it reads"
    return f"the {kind}{offset} {how}"


def training_time(run_dir: str | Path) -> str | None:
    """'N steps, about T' of the training logged in run_dir's metrics.jsonl (every part of a resumed
    run; the steps between logs at their logged rate), or None without a logged rate."""
    path = Path(run_dir) / "metrics.jsonl"
    if not path.is_file():
        return None
    seconds, last = 0.0, 0
    for line in path.read_text().splitlines():
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            continue
        rate = record.get("steps_per_s")
        if rate and record.get("step", 0) > last:
            seconds += (record["step"] - last) / rate
            last = record["step"]
    return f"{last} steps, about {duration(seconds)}" if last else None


def _linear_name(result: dict, kind: str) -> str:
    """'ARX(7, 5)' / 'N4SID(4)': a fitted linear model of the selection with its orders."""
    orders = result.get("linear_orders", {}).get(kind) or {}
    if not orders:
        return NAMES[kind]
    shown = [str(v) if kind == ARX.kind else f"{k}={v}" for k, v in orders.items()]
    return f"{NAMES[kind]}({', '.join(shown)})"


def kept_model(result: dict) -> str:
    """The least-squares model a selection kept, named with its orders ('ARX(3, 10)', 'least-squares
    feature, NARX(p=40, q=40, c=0)'); "network" where it kept the network."""
    kept = result.get("kept", "network")
    return kept if kept == "network" else _linear_name(result, kept)


READINGS = {
    "gap": "reading its simulated outputs as missing, as it trained",
    "rollout": "feeding its predictions back as outputs",
}


def selection_line(result: dict, feature: str | None = None, trained: str | None = None) -> str:
    """One line for the user: the check's scores and what the run keeps, in plain words.

    feature: what the correction at gain 0 leaves (e.g. "the ARX(40, 40) with an intercept fixed at its
    least-squares fit on the training part"; default "its input feature"); trained: the training it took
    (e.g. "1875 steps, 1 min 02 s"). Each score is the mean of the held-out simulation's RMSE and the long
    free run's. Where the kept gain is 0 the network did not help: the line says the model is the feature
    alone and what training that was. Where the network is kept at a gain above 0 it names the reading, the
    gain and the scores (as kept, as trained and of the feature alone).
    """
    linear = ", ".join(
        f"fitted {_linear_name(result, k)} {v['score']:.4g}" for k, v in result["linear_models"].items()
    )
    both = (
        f"held-out check (mean RMSE of the held-out simulation, {result['held_out_steps']} steps, and a long "
        f"free run, {result['long_run_steps']} steps, each after {result['init']} measured): network as "
        f"trained {result['network_rmse']:.4g}, {linear}"
    )
    spent = f" ({trained} of training)" if trained else ""
    if result["kept"] == "network":
        gain, reading = result["gain"], result["reading"]
        by_gain = {g: s["score"] for g, s in zip(result["gains"], result["network"][reading], strict=True)}
        how = READINGS.get(reading, reading) if len(result["network"]) > 1 else ""
        if gain == 0:
            alone = feature or "its input feature"
            return (
                f"{both}: the network's correction did not help: the run's model is its feature alone, "
                f"{alone} (correction at gain 0, {by_gain[0.0]:.4g}); the training{spent} did not improve "
                "on it"
            )
        scaled = "as trained" if gain == 1.0 else f"with its correction at gain {gain:g}"
        extra = (
            f" ({by_gain[gain]:.4g}; its feature alone, gain 0: {by_gain[0.0]:.4g})" if 0.0 in by_gain else ""
        )
        return f"{both}: the run keeps the network {scaled}{', ' + how if how else ''}{extra}{spent}"
    kind = result["kept"]
    written = f"as `mop fit {kind}` writes it" if kind in LINEAR else "as the check scored it"
    return (
        f"{both}: the network does not beat the least-squares models, so the run keeps the fitted "
        f"{_linear_name(result, kind)} (fitted.json, {written}): `mop predict` and "
        f"mop.load use it; the training{spent} did not improve on it"
    )
