"""The identifiers and the recorded training data take mop.Record: fitting records gives what fitting their
(y, u) pairs gives (the older form, still accepted through mop.record.to_records), and an ARX fitted on
noise-free ARX data recovers its coefficients."""

import numpy as np
import pytest

from mop.config import DataConfig
from mop.identify.select import feasible_order, fit, fit_orders
from mop.record import Record, as_pairs, read_records, to_records
from mop.train.records import read_recorded


def arx_records(num: int = 2, T: int = 200, inputs: bool = True) -> list[Record]:
    """Noise-free y_{t+1} = 0.7 y_t - 0.2 y_{t-1} + 0.5 u_t + 0.1 (one output, one input or none)."""
    rng = np.random.default_rng(3)
    out = []
    for i in range(num):
        u = rng.normal(size=(T, 1)) if inputs else np.zeros((T, 1))
        y = np.zeros((T, 1))
        y[:2] = rng.normal(size=(2, 1))
        for t in range(1, T - 1):
            y[t + 1] = 0.7 * y[t] - 0.2 * y[t - 1] + 0.5 * u[t] + 0.1
        out.append(Record(y=y, u=u if inputs else None, name=f"r{i}"))
    return out


def test_to_records_reads_a_record_records_and_pairs():
    records = arx_records()
    assert to_records(records[0]) == [records[0]]
    assert to_records(records) == records
    again = to_records(as_pairs(records))
    assert [r.name for r in again] == ["0", "1"]
    for a, b in zip(again, records, strict=True):
        assert np.array_equal(a.y, b.y) and np.array_equal(a.u, b.u)
    assert to_records([(records[0].y, None)])[0].u is None


@pytest.mark.parametrize("inputs", [True, False])
@pytest.mark.parametrize("kind", ["arx", "n4sid"])
def test_fitting_records_equals_fitting_their_pairs(kind, inputs):
    records = arx_records(inputs=inputs)
    pairs = as_pairs(records)
    assert fit(kind, records, max_order=4).to_json() == fit(kind, pairs, max_order=4).to_json()
    assert fit(kind, records[0], max_order=3).to_json() == fit(kind, pairs[:1], max_order=3).to_json()
    orders = {"p": 2, "q": 1 if inputs else 0} if kind == "arx" else {"n": 2}
    given = fit_orders(kind, records, orders), fit_orders(kind, pairs, orders)
    assert given[0].to_json() == given[1].to_json()
    assert feasible_order(kind, records) == feasible_order(kind, pairs)


def test_an_arx_fitted_on_noise_free_arx_records_recovers_them():
    """ARX(2, 1)'s least squares on records of that ARX: the one-step prediction is exact."""
    records = arx_records()
    fitted = fit_orders("arx", records, {"p": 2, "q": 1})
    C, d = fitted.model.C, fitted.model.d
    np.testing.assert_allclose(C[0, :2], [0.7, -0.2], atol=1e-9)
    np.testing.assert_allclose(C[0, 2], 0.5, atol=1e-9)
    np.testing.assert_allclose(d, [0.1], atol=1e-9)


def test_recorded_data_reads_the_files_records(tmp_path):
    """RecordedData's parts are the file's records [y, u] side by side, and RecordedData.records gives
    those records back."""
    records = arx_records(num=4)
    path = tmp_path / "rec.npz"
    np.savez(path, y=np.stack([r.y for r in records]), u=np.stack([r.u for r in records]))
    data = read_recorded(DataConfig(path=str(path), split="time"))
    assert (data.output_dim, data.input_dim, data.num_trajectories) == (1, 1, 4)
    whole = [np.concatenate([r.y, r.u], axis=1) for r in read_records(path)]
    for part, val, full in zip(data.train_parts, data.val_parts, whole, strict=True):
        assert np.array_equal(np.concatenate([part, val]), full)
    back = data.records(data.train_parts)
    assert all(
        np.array_equal(b.y, a[:, :1]) and np.array_equal(b.u, a[:, 1:])
        for b, a in zip(back, data.train_parts, strict=True)
    )
