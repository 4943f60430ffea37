"""Run predictors on test trajectories and summarise their errors (the eval.json of `mop reproduce`).

traj = make_family(cfg).generate(N, T, generator=g)
result = evaluate([KalmanPredictor(), model], traj)         # {name: e (N, T+1)}
summary = summarize(result, reference="kalman")            # eval.json "predictors" + windows + ratios
"""

from __future__ import annotations

import time

from mop.errors import MopError
from mop.metrics import error_curves, errors, mse_ratio_ci, window_mean
from mop.predictors import Predictor
from mop.progress import progress as make_progress
from mop.systems.base import Trajectories


def evaluate(predictors: list[Predictor], traj: Trajectories, progress: bool = True) -> dict[str, dict]:
    """{name: {"e": (N, T+1) per-system errors ||yhat_t - y_t||_2, "seconds": wall time}}.

    Every predictor sees the same trajectories.
    """
    out = {}
    bar = make_progress(len(predictors), "evaluate", disable=not progress)
    for p in predictors:
        bar.set_postfix(predictor=p.name)
        start = time.perf_counter()
        yhat = p.predict(traj)  # (N, T+1, m)
        if yhat.shape != traj.y.shape:
            raise MopError(
                f"predictor {p.name} returned shape {tuple(yhat.shape)}, expected {tuple(traj.y.shape)}"
            )
        out[p.name] = {"e": errors(yhat, traj.y), "seconds": time.perf_counter() - start}
        bar.update(1)
    bar.close()
    return out


def windows(horizon: int) -> dict[str, tuple[int, int]]:
    """The report's time windows: [1,10], [10,20), [20,T) (clipped to T) and all t >= 1."""
    return {
        "[1,10]": (1, 11),
        "[10,20)": (10, 20),
        f"[20,{horizon + 1})": (20, horizon + 1),
        "all": (1, horizon + 1),
    }


def summarize(result: dict[str, dict], reference: str, seed: int = 0) -> dict:
    """eval.json body: per-predictor curves and window means, and every predictor's MSE ratio to `reference`.

    Ratios come with paired bootstrap 95% CIs over test systems.
    """
    first = next(iter(result.values()))["e"]
    horizon = first.shape[1] - 1
    wins = windows(horizon)
    predictors = {}
    for name, r in result.items():
        curves = error_curves(r["e"])
        curves["window_error"] = {w: window_mean(curves["error"], *span) for w, span in wins.items()}
        curves["window_squared_error"] = {
            w: window_mean(curves["squared_error"], *span) for w, span in wins.items()
        }
        curves["seconds"] = r["seconds"]
        predictors[name] = curves
    ratios = {}
    if reference in result:
        for name in result:
            if name == reference:
                continue
            e_num, e_den = result[name]["e"], result[reference]["e"]
            ratios[name] = {
                w: dict(
                    zip(("ratio", "low", "high"), mse_ratio_ci(e_num, e_den, *span, seed=seed), strict=True)
                )
                for w, span in wins.items()
                if span[0] < span[1] <= horizon + 1
            }
    return {
        "num_systems": int(first.shape[0]),
        "horizon": horizon,
        "predictors": predictors,
        "ratios_to_reference": {
            "reference": reference,
            "method": "paired percentile bootstrap over test systems, 2000 resamples, seeded",
            "ratios": ratios,
        },
    }
