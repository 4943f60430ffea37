"""mop.records: the field's figures of merit against their closed forms, and padded batches of unequal
lengths equal to one trajectory at a time."""

import numpy as np
import pytest

from mop.predictors import make_predictor
from mop.records import predict_all, scores, simulate_all


def test_fit_and_nrmse_closed_forms():
    rng = np.random.default_rng(0)
    y = rng.normal(3.0, 2.0, size=(500, 2))
    mean = y.mean(0)
    assert scores(y, y).fit == pytest.approx(100) and scores(y, y).rmse == 0
    assert scores(y, np.broadcast_to(mean, y.shape)).fit == pytest.approx(0, abs=1e-9)  # the mean: fit 0
    half = mean + 0.5 * (y - mean)  # half the deviation: ||e|| = ||y - mean|| / 2 per channel
    s = scores(y, half)
    assert s.fit == pytest.approx(50) and s.nrmse == pytest.approx(0.5)
    assert s.rmse == pytest.approx(np.sqrt(((y - half) ** 2).mean()))
    # channels scaled apart: fit and NRMSE are per channel, so scaling one channel changes neither
    scaled = scores(y * [1, 1000], half * [1, 1000])
    assert scaled.fit == pytest.approx(50) and scaled.nrmse == pytest.approx(0.5)


def test_missing_outputs_are_left_out_and_lists_pool():
    y = np.array([[1.0], [np.nan], [3.0], [5.0]])
    p = np.array([[2.0], [100.0], [3.0], [5.0]])
    s = scores(y, p)
    assert s.steps == 3 and s.rmse == pytest.approx(np.sqrt(1 / 3))
    pooled = scores([y[:2], y[2:]], [p[:2], p[2:]])
    assert pooled == s


def test_unequal_lengths_equal_one_at_a_time():
    rng = np.random.default_rng(1)
    data = [(rng.normal(size=(n, 2)), rng.normal(size=(n, 1))) for n in (12, 30, 20)]
    arx = make_predictor("arx")
    together = predict_all(arx, data)
    sims = simulate_all(arx, data, 5)
    for i, record in enumerate(data):
        alone = predict_all(arx, [record])[0]
        np.testing.assert_allclose(together[i], alone, rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(sims[i], simulate_all(arx, [record], 5)[0], rtol=1e-6, atol=1e-6)
        assert sims[i].shape == (len(record[0]) - 5, 2)
