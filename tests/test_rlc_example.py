"""The RLC-circuit example (examples/rlc_circuit.py, a family with inputs written outside the package):
its exact zero-order-hold model against scipy, its process-noise covariance against quadrature, its
trajectories against the Kalman filter (the innovations of the KF that knows each circuit are white with the
filter's own variance, so simulate and state_space agree) and against filterpy, and its experiment file
(examples/rlc_circuit.toml) end to end on the smoke preset."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.integrate import quad_vec
from scipy.linalg import expm
from scipy.signal import cont2discrete

from mop import cli
from mop.experiments.files import import_plugin
from mop.predictors import make_predictor
from mop.systems import generator
from tests.reference import filterpy_predict

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


@pytest.fixture(scope="module")
def rlc():
    """The family, registered by importing the plugin; (its config class, a float64 family of it)."""
    import_plugin(EXAMPLES / "rlc_circuit.py")
    from mop.systems import FAMILIES

    family_class = FAMILIES.get("rlc-circuit")
    return lambda **knobs: family_class(family_class.Config(**knobs), torch.float64)


def continuous(R: float, L: float, C: float) -> tuple[np.ndarray, np.ndarray]:
    """The series RLC circuit written out independently of the example: x = (v_C, i_L)."""
    return np.array([[0.0, 1.0 / C], [-1.0 / L, -R / L]]), np.array([[0.0], [1.0 / L]])


@pytest.mark.parametrize("output", ["both", "capacitor"])
def test_zero_order_hold_matches_scipy(rlc, output):
    """A, B of 64 random circuits == scipy.signal.cont2discrete(method="zoh") to 1e-10; C, R as documented."""
    family = rlc(output=output)
    p = family.sample(64, generator=generator(5))
    dt = family.config.dt
    for b in range(64):
        R, L, C = (float(v[b]) for v in (p.resistance, p.inductance, p.capacitance))
        A_c, b_c = continuous(R, L, C)
        A, B, *_ = cont2discrete((A_c, b_c, np.eye(2), np.zeros((2, 1))), dt, method="zoh")
        np.testing.assert_allclose(p.A[b].numpy(), A, rtol=0, atol=1e-10)
        np.testing.assert_allclose(p.B[b].numpy(), B, rtol=0, atol=1e-10 * np.abs(B).max())
        out = np.array([[1.0, 0.0], [0.0, R]])[: family.output_dim]  # y = (v_C, R i_L) or v_C alone
        np.testing.assert_allclose(p.C[b].numpy(), out, rtol=1e-12)
    assert torch.linalg.eigvals(p.A).abs().max() < 0.99  # stable, as the docstring promises
    R = family.config.output_std**2 * np.eye(family.output_dim)
    np.testing.assert_allclose(p.R.numpy(), np.broadcast_to(R, p.R.shape), rtol=1e-15)


def test_parameters_lie_in_their_ranges(rlc):
    family = rlc()
    p = family.sample(2000, generator=generator(6))
    for key, v in (
        ("resistance", p.resistance),
        ("inductance", p.inductance),
        ("capacitance", p.capacitance),
    ):
        low, high = family.config.bounds(key)
        assert low <= v.min() and v.max() <= high
        log = (v.log() - np.log(low)) / (np.log(high) - np.log(low))  # log-uniform: U[0, 1]
        assert abs(float(log.mean()) - 0.5) < 0.02 and abs(float(log.var()) - 1 / 12) < 0.01


def test_process_noise_covariance_matches_quadrature(rlc):
    """Q = sigma^2 dt int_0^dt expm(A_c s) b b^T expm(A_c s)^T ds (Van Loan) == scipy's quadrature."""
    family = rlc()
    cfg = family.config
    p = family.sample(8, generator=generator(7))
    for b in range(8):
        A_c, b_c = continuous(*(float(v[b]) for v in (p.resistance, p.inductance, p.capacitance)))
        integrand = lambda s, A_c=A_c, b_c=b_c: expm(A_c * s) @ b_c @ b_c.T @ expm(A_c * s).T  # noqa: E731
        Q, _ = quad_vec(integrand, 0.0, cfg.dt, epsabs=0, epsrel=1e-13)
        Q *= cfg.disturbance_std**2 * cfg.dt
        np.testing.assert_allclose(p.Q[b].numpy(), Q, rtol=1e-9, atol=1e-12 * np.abs(Q).max())
        assert np.linalg.eigvalsh(Q).min() > 0  # full rank: (A_c, b) is controllable


def test_kalman_innovations_are_white_with_the_filters_variance(rlc):
    """On 4000 simulated circuits (T = 50), e_t = (y_t - yhat_t) / sqrt(var_t) from the KF that knows each
    circuit has, per output channel: E[e_t^2] = 1 at every t (tolerance 0.1, about 4.5 standard errors of
    a mean of 4000 squares), E[e^2] = 1 over all t (0.02, about 4.5 s.e.), and no correlation between
    e_t and e_{t-k}, k = 1..3, within or across channels (|corr| < 0.02, about 4.5 s.e.). A simulation
    that disagreed with state_space (wrong Q, P0, B or noise draws) would break this."""
    traj = rlc().generate(4000, 50, generator=generator(8))
    mean, var = make_predictor("kalman").predict_distribution(traj)
    assert var.shape == traj.y.shape  # per-channel predictive variances
    e = ((traj.y - mean) / var.sqrt()).numpy()  # (N, T+1, m)
    per_step = (e**2).mean(0)  # (T+1, m)
    assert np.abs(per_step - 1).max() < 0.1, per_step
    assert np.abs((e**2).mean((0, 1)) - 1).max() < 0.02
    for k in (1, 2, 3):
        lagged = np.einsum("bti,btj->ij", e[:, k:], e[:, :-k]) / (e.shape[0] * (e.shape[1] - k))
        assert np.abs(lagged).max() < 0.02, (k, lagged)


def test_kalman_matches_filterpy_on_the_circuits(rlc):
    traj = rlc().generate(4, 30, generator=generator(9))
    p = traj.params.map(torch.Tensor.numpy)
    ref = filterpy_predict(p.A, p.C, p.Q, p.R, traj.y.numpy(), p.x0_mean, p.P0, p.B, traj.u.numpy())
    np.testing.assert_allclose(make_predictor("kalman").predict(traj).numpy(), ref, rtol=1e-10, atol=1e-12)


def test_same_seed_same_circuits(rlc):
    one, two = (rlc().generate(5, 20, generator=generator(3)) for _ in range(2))
    assert torch.equal(one.y, two.y) and torch.equal(one.u, two.u) and torch.equal(one.params.A, two.params.A)


def test_bad_knob_is_one_line_error(capsys):
    argv = ["reproduce", str(EXAMPLES / "rlc_circuit.toml"), "--preset", "smoke", "system.output=voltage"]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "output is 'both' or 'capacitor'" in err


def test_rlc_experiment_file_end_to_end(tmp_path, tiny_smoke):
    out = tmp_path / "rlc"
    argv = [
        "reproduce",
        str(EXAMPLES / "rlc_circuit.toml"),
        "--preset",
        "smoke",
        "--out",
        str(out),
        "--quiet",
        "--bayes",  # the Bayes mixture over the family, which the smoke and small presets leave out
    ]
    assert cli.main(argv) == 0
    data = json.loads((out / "eval.json").read_text())
    assert data["experiment"] == "rlc-circuit" and data["num_systems"] == 6
    assert {"mop", "kalman", "bayes", "arx", "n4sid-kf", "last", "zero"} <= set(data["predictors"])
    bayes, arx = (data["predictors"][k]["window_error"] for k in ("bayes", "arx"))
    assert all(bayes[w] < arx[w] for w in bayes)  # knowing the family beats identifying from nothing
    assert data["claims"][0]["claim"].startswith("MOP is within 10% of the Kalman filter")
    kf, last = (data["predictors"][k]["window_error"] for k in ("kalman", "last"))
    assert all(np.isfinite(v) for v in kf.values())
    assert all(kf[w] < last[w] for w in kf)  # the optimal filter beats repeating the last output
    assert (out / "rlc-circuit_error.png").exists() and "| kalman |" in (out / "report.md").read_text()
    again = [
        "reproduce",
        str(EXAMPLES / "rlc_circuit.toml"),
        "--preset",
        "smoke",
        "--out",
        str(tmp_path / "again"),
    ]
    assert cli.main([*again, "--runs", str(tmp_path / "runs"), "--quiet"]) == 0  # reuses the trained run
    assert len(list((tmp_path / "runs").iterdir())) == 1
