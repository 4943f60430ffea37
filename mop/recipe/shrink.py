"""The correction's gain of a fine-tuned class model, chosen by free-run simulation of its estimation records.

A class model predicts yhat_{t+1} = r_{t+1} + s_t (W_out h_t + b_out) (mop.models.features.restore): its ARX
feature's prediction r plus the network's correction, s the correction's scale. Multiplying the read-out
(W_out, b_out) by a gain g gives a model of the same architecture with g times the correction: g = 0 is the
feature alone (in a fine-tune, the ARX fitted by least squares on the estimation record), g = 1 the
fine-tuned model as trained.

With train.shrink_correction, after training (and after train.keep_best has loaded the kept weights;
mop.recipe.training hands apply_chosen_gain to the training loop as its step after the last) each gain of
GAINS simulates every record of data.path from its start (y_0 its initial condition, y_1..y_T simulated from
the inputs, as `mop predict RUN rec.csv --simulate 0`), and the gain of the lowest RMSE over them is written
into the run's model.safetensors; shrink.json holds every gain's RMSE.

Why: a fine-tune trains on windows of about a tenth of one record (mop.recipe.finetune.record_horizon),
with simulated tails no longer than they are, and validates on the record's last tenth. On nearly linear
plants its correction then drifts over a record-long free run where the fitted ARX does not, and nothing in
training sees it (tank_records plant 2: the fine-tune simulates est.csv at 0.60 against its feature's
0.52). The gain is one number chosen on the estimation record alone, so the validation record stays unseen;
on plants where the network's correction is worth its whole size the choice is g = 1 and nothing changes.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from torch import nn

from mop.atomic import write_json
from mop.checkpoint import save_model
from mop.config import RunConfig
from mop.errors import MopError
from mop.models.predictor import LearnedPredictor, Normalization
from mop.predictors import simulate
from mop.systems.base import Trajectories
from mop.train.records import TrainingRecords, recorded_data

GAINS = (0.0, 0.25, 0.5, 0.75, 1.0)
SHRINK_FILE = "shrink.json"  # in the run directory: every gain's RMSE and the one chosen


def check_shrink(config: RunConfig) -> None:
    """One-line MopError where train.shrink_correction cannot apply (before any training)."""
    if not config.train.shrink_correction:
        return
    m = config.model
    if config.data is None or m.arch != "gpt" or m.readout != "mean" or m.rls_order == 0:
        raise MopError(
            "train.shrink_correction=true scales a model's correction to its input feature on recorded data: "
            "it needs --data, model.arch='gpt', model.readout='mean' and a feature (model.rls_order > 0)"
        )


def scale_correction(model: nn.Module, gain: float) -> None:
    """Multiply the network's correction by `gain` (in place): the read-out's weight and bias."""
    with torch.no_grad():
        model.read_out.weight.mul_(gain)
        model.read_out.bias.mul_(gain)


def simulation_rmse(model: nn.Module, config: RunConfig, records: TrainingRecords | None = None) -> float:
    """RMSE of the free-run simulation of every estimation record (`records` in memory, else data.path's)
    from its start (t >= 1, in the records' units, pooled over records and output channels; missing outputs
    left out)."""
    d = config.data
    norm = Normalization.from_lists(d.y_mean, d.y_std, d.u_mean, d.u_std)
    predictor = LearnedPredictor(model, normalization=norm, source=str(config.train.init))
    sq, n = 0.0, 0
    for record in recorded_data(d, records).given.records:
        y, u = record.y, record.u
        traj = Trajectories(
            y=torch.tensor(y[None], dtype=torch.float32),
            u=None if u is None else torch.tensor(u[None], dtype=torch.float32),
            params=None,
            family="",
        )
        e = simulate(predictor, traj, 1)[0].double().numpy() - y[1:]  # (T, m)
        sq, n = sq + float(np.nansum(e**2)), n + int(np.isfinite(e).sum())
    return float(np.sqrt(sq / max(n, 1)))


def gain_scores(
    model: nn.Module, score: Callable[[], float], gains: tuple[float, ...] = GAINS
) -> list[float]:
    """score() with `model`'s correction scaled by each gain of `gains` in turn; the model is left as it
    was (its read-out restored, its train/eval mode too)."""
    was_training = model.training
    model.eval()
    kept = {k: v.clone() for k, v in model.read_out.state_dict().items()}
    scores = []
    for gain in gains:
        model.read_out.load_state_dict(kept)
        scale_correction(model, gain)
        scores.append(score())
    model.read_out.load_state_dict(kept)
    model.train(was_training)
    return scores


def best_gain(scores: list[float]) -> float:
    """The gain of GAINS of the lowest score; on a tie the larger gain."""
    return GAINS[min(range(len(GAINS)), key=lambda i: (scores[i], -GAINS[i]))]


def choose_gain(
    model: nn.Module, config: RunConfig, records: TrainingRecords | None = None
) -> dict[str, object]:
    """Scale `model`'s correction (in place) by the gain of GAINS that simulates data.path best; returns
    {"gains": GAINS, "free_run_rmse": [RMSE per gain], "gain": chosen}. On a tie the larger gain is kept."""
    rmse = gain_scores(model, lambda: simulation_rmse(model, config, records))
    gain = best_gain(rmse)
    scale_correction(model, gain)
    return {"gains": list(GAINS), "free_run_rmse": rmse, "gain": gain}


def apply_chosen_gain(
    config: RunConfig, model: nn.Module, out_dir: Path, records: TrainingRecords | None = None
) -> None:
    """With train.shrink_correction, once a run has trained: scale `model`'s correction by choose_gain's
    gain and write it to out_dir's model.safetensors, then shrink.json (after the weights, so a resumed run
    that finds shrink.json has the scaled weights already and leaves them)."""
    shrunk = out_dir / SHRINK_FILE
    if not config.train.shrink_correction or shrunk.exists():
        return
    choice = choose_gain(model, config, records)
    save_model(out_dir / "model.safetensors", model)
    write_json(shrunk, choice)


def shrink_line(choice: dict, path: str) -> str:
    """One line saying which gain was kept and why (from shrink.json's contents)."""
    rmse = dict(zip(choice["gains"], choice["free_run_rmse"], strict=True))
    others = ", ".join(f"{g:g}: {r:.4g}" for g, r in rmse.items() if g != choice["gain"])
    return (
        f"correction: kept at gain {choice['gain']:g} (0: the feature alone, 1: as trained), the best "
        f"free-run simulation of {path} from its start: RMSE {rmse[choice['gain']]:.4g} ({others}; "
        "train.shrink_correction)"
    )
