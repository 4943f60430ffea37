"""A fine-tune's "feature alone" is the feature its line names (issue #66, A): a class model fine-tuned with
its ARX feature fixed at the least-squares fit on the training part simulates the held-out tail, at the
correction's gain 0, exactly as that ARX does, also where the tail's simulation starts after outputs of a
plant at rest (the free run is then not held within the span of those few outputs)."""

import numpy as np
import pytest

from mop.recipe.fit import fine_tune_record
from mop.recipe.records import feature_line
from mop.record import Record, write_records
from mop.train.records import TrainingRecords

P, Q = 4, 4
N, VAL = 1500, 150  # data.validation_fraction 0.1: the last 150 samples are held out


@pytest.fixture(autouse=True)
def _one_thread(one_thread):
    yield


def plant_at_rest_before_the_tail(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A damped second-order plant with a softly saturating actuator; its input is off from sample 1150 to
    1360, so the 50 outputs measured before the held-out tail (1300..1349) are those of a plant at rest."""
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.normal(size=N // 10), 10)
    u[1150:1360] = 0.0
    y = np.zeros(N)
    x1 = x2 = 0.0
    for t in range(N):
        y[t] = x1 + 1e-3 * rng.normal()
        x1, x2 = 1.6 * x1 - 0.7 * x2 + 0.3 * np.tanh(u[t]), x1
    return y, u


def arx_held_out_rmse(y: np.ndarray, u: np.ndarray) -> float:
    """The ARX(P, Q) with an intercept fitted by least squares (numpy) on the training part, simulated
    from the inputs over the held-out tail after the 50 measured outputs before it: the RMSE."""
    cut, r = N - VAL, max(P, Q)
    rows = [np.r_[y[t - P : t][::-1], u[t - Q : t][::-1], 1.0] for t in range(r, cut)]
    theta = np.linalg.lstsq(np.array(rows), y[r:cut], rcond=None)[0]
    sim = y.copy()
    for t in range(cut, N):
        sim[t] = np.r_[sim[t - P : t][::-1], u[t - Q : t][::-1], 1.0] @ theta
    return float(np.sqrt(np.mean((sim[cut:] - y[cut:]) ** 2)))


def test_a_fine_tunes_feature_alone_is_the_fitted_arx_it_names(tmp_path):
    y, u = plant_at_rest_before_the_tail()
    path = write_records([Record(y=y[:, None], u=u[:, None])], tmp_path / "est.csv")
    overrides = [
        f"model.rls_order={P}",
        f"model.arx_order={Q}",
        "model.rls_prior=fit",
        "model.rls_fixed=true",
        "model.rls_p0=1",
        "train.steps=1",
    ]
    lines = []
    fitted = fine_tune_record(
        tmp_path / "ft",
        TrainingRecords.read(path),
        "pretrained:lti-siso",
        overrides=overrides,
        progress=False,
        announce=lines.append,
    )
    assert f"ARX({P}, {Q}) with an intercept" in feature_line(fitted.config)
    assert "fixed at its least-squares fit on the training part" in feature_line(fitted.config)
    reading = fitted.config.model.forecast_mode
    gain0 = fitted.selection["network"][reading][fitted.selection["gains"].index(0.0)]["held_out"]
    assert gain0 == pytest.approx(arx_held_out_rmse(y, u), rel=2e-3)
    kept = fitted.selection["kept"]
    said = {"arx": "keeps the fitted ARX", "n4sid": "keeps the fitted N4SID"}.get(kept, "keeps the network")
    if fitted.selection["gain"] == 0:
        said = f"its feature alone, the ARX({P}, {Q}) with an intercept fixed at its least-squares fit"
    assert said in lines[-1]
