"""model.residual_scale = "running": the correction to the ARX feature scaled by the feature's recent error,
against the definition written out in numpy, and what it is for: where the feature is exact (a noise-free
ARX record) the model's predictions stay on it whatever the network's weights."""

import numpy as np
import pytest
import torch

from mop.config import ModelConfig
from mop.errors import MopError
from mop.models.features import RESIDUAL_FLOOR, residual_from, residual_scale, residual_update
from tests.test_recordnorm import tiny, trained_like


@pytest.mark.parametrize("mode,lam", [("running", 0.5), ("measured", 0.5), ("measured", 0.9)])
def test_residual_scale_is_the_weighted_mean_of_the_measured_errors(mode, lam):
    """ "measured": the same where y_t is measured, the record's std where it is missing."""
    g = np.random.default_rng(0)
    B, T, m = 2, 15, 2
    y, base, std = g.normal(size=(B, T, m)), g.normal(size=(B, T, m)), g.uniform(0.5, 2, size=(B, T, m))
    seen = g.uniform(size=(B, T, m)) > 0.3
    y_nan = np.where(seen, y, np.nan)
    tensors = (torch.tensor(a) for a in (y_nan, base, seen, std))
    got = residual_scale(*tensors, mode, lam)
    want = np.zeros((B, T, m))
    for b in range(B):
        for j in range(m):
            for t in range(T):
                s = [s for s in range(1, t + 1) if seen[b, s, j]]  # the measured errors so far
                w = np.array([lam ** (len(s) - 1 - i) * (1 - lam) for i in range(len(s))])  # k back: lam^k
                e2 = np.array([(y[b, s_, j] - base[b, s_ - 1, j]) ** 2 for s_ in s])
                mean_sq = (w @ e2) / w.sum() if s else std[b, t, j] ** 2
                want[b, t, j] = np.sqrt(mean_sq + RESIDUAL_FLOOR * std[b, t, j] ** 2)
                if mode == "measured" and not seen[b, t, j]:
                    want[b, t, j] = std[b, t, j]
    np.testing.assert_allclose(got.numpy(), want, rtol=1e-12)


@pytest.mark.parametrize("lam", [0.5, 0.95])
def test_the_whole_window_at_once_equals_the_step_recursion_on_long_records(lam):
    """residual_scale (every position at once) against residual_update / residual_from stepped through
    3000 positions, as the stream steps them: long enough that lam^-k overflows float64 at lam = 0.5
    (2^3000), with gaps, a gap from the start, and an output whose errors are all 0."""
    g = torch.Generator().manual_seed(0)
    B, T, m = 3, 3000, 2
    y, base = torch.randn(B, T, m, generator=g, dtype=torch.float64), torch.randn(B, T, m, generator=g)
    std = torch.rand(B, T, m, generator=g, dtype=torch.float64) + 0.5
    seen = torch.rand(B, T, m, generator=g) > 0.2
    seen[1, :700] = False  # nothing measured for 700 steps
    base[2, :-1, 1] = y[2, 1:, 1].float()  # output 1 of system 2: every error 0 (up to float32 rounding)
    y = torch.where(seen, y, torch.full_like(y, float("nan")))
    got = residual_scale(y, base, seen, std, "measured", lam)
    v, n = torch.zeros(B, m, dtype=torch.float64), torch.zeros(B, m, dtype=torch.float64)
    want = []
    for t in range(T):
        if t > 0:
            v, n = residual_update(v, n, y[:, t], base[:, t - 1].double(), seen[:, t], lam)
        want.append(residual_from(v, n, std[:, t], seen[:, t]))
    torch.testing.assert_close(got, torch.stack(want, 1), rtol=1e-10, atol=0)


def _noise_free_arx_record(T: int = 200) -> torch.Tensor:
    """(3, T, 2) [y, u]: y_t = 0.6 y_{t-1} - 0.2 y_{t-2} + 0.5 u_{t-1} + 0.3 u_{t-2} exactly."""
    g = torch.Generator().manual_seed(1)
    u = torch.randn(3, T, generator=g, dtype=torch.float64)
    y = torch.zeros(3, T, dtype=torch.float64)
    y[:, :2] = torch.randn(3, 2, generator=g, dtype=torch.float64)
    for t in range(2, T):
        y[:, t] = 0.6 * y[:, t - 1] - 0.2 * y[:, t - 2] + 0.5 * u[:, t - 1] + 0.3 * u[:, t - 2]
    return torch.stack([y, u], -1)


def test_on_an_exact_feature_any_network_stays_on_it():
    """Random weights (the read-out's too): with the residual scale the late predictions equal y to about
    1e-4 of the record's std (the floor), the error of the same network scaled by std_t(y) is of order std."""
    z = _noise_free_arx_record()
    options = {"rls_order": 2, "arx_order": 2, "rls_offset": True, "rls_p0": 1e4}  # the intercept: the frame
    errors = {}
    for scale in ("none", "running"):
        model = trained_like(tiny(residual_scale=scale, context=200, **options))
        with torch.no_grad():
            yhat = model(z)[:, 180:-1, 0]  # predictions of y_181..y_199, long after identification
        errors[scale] = float((yhat - z[:, 181:, 0]).abs().max())
    std = float(z[..., 0].std())
    assert errors["running"] < 1e-2 * std < errors["none"], errors


def test_residual_scale_needs_the_feature_and_the_record_norm():
    with pytest.raises(MopError, match="residual_scale"):
        ModelConfig(residual_scale="running")
    with pytest.raises(MopError, match="residual_scale"):
        tiny(residual_scale="running")  # record_norm but no feature
    with pytest.raises(MopError, match="residual_decay"):
        ModelConfig(residual_decay=1.0)
