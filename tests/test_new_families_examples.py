"""The plugin families written for model.features=auto's check (examples/thermal_network.py,
examples/dead_time.py, examples/two_mass.py): each model against an independent construction (scipy's
zero-order hold and quadrature; the plant's transfer function by scipy.signal), the Kalman filter's
innovations white with its own variance (simulate and state_space agree), and each experiment file end to
end on the smoke preset."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.integrate import quad_vec
from scipy.linalg import expm
from scipy.signal import cont2discrete, dimpulse

from mop import cli
from mop.experiments.files import import_plugin
from mop.predictors import make_predictor
from mop.systems import generator

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def family(name: str, plugin: str, **knobs):
    import_plugin(EXAMPLES / plugin)
    from mop.systems import FAMILIES

    cls = FAMILIES.get(name)
    return cls(cls.Config(**knobs), torch.float64)


def thermal_continuous(c, g, k) -> tuple[np.ndarray, np.ndarray]:
    """The chain written out node by node: c_i dx_i/dt = -g_i x_i + sum_neighbours k (x_j - x_i) + [i=0] u."""
    n = len(c)
    A = np.zeros((n, n))
    for i in range(n):
        A[i, i] -= g[i]
        for j in (i - 1, i + 1):
            if 0 <= j < n:
                kij = k[min(i, j)]
                A[i, i] -= kij
                A[i, j] += kij
    A /= np.asarray(c)[:, None]
    b = np.zeros((n, 1))
    b[0, 0] = 1 / c[0]
    return A, b


def test_thermal_network_matches_scipy_hold_and_quadrature():
    fam = family("thermal-network", "thermal_network.py", num_nodes=3, dt=0.5)
    p = fam.sample(16, generator=generator(1))
    q = fam.config.disturbance_std
    for s in range(16):
        c, g, k = (v[s].numpy() for v in (p.capacity, p.ambient, p.coupling))
        A_c, b = thermal_continuous(c, g, k)
        A, B, *_ = cont2discrete((A_c, b, np.eye(3), np.zeros((3, 1))), fam.config.dt, method="zoh")
        np.testing.assert_allclose(p.A[s].numpy(), A, rtol=0, atol=1e-12)
        np.testing.assert_allclose(p.B[s].numpy(), B, rtol=1e-10, atol=1e-14)
        G = q * np.diag(1 / c)
        Q, _ = quad_vec(
            lambda t, A_c=A_c, G=G: expm(A_c * t) @ G @ G.T @ expm(A_c * t).T, 0, fam.config.dt, epsrel=1e-12
        )
        np.testing.assert_allclose(p.Q[s].numpy(), Q, rtol=1e-8, atol=1e-14)
        lam = np.linalg.eigvals(A_c)
        assert np.abs(lam.imag).max() < 1e-9 and lam.real.max() < 0  # relaxes to ambient, no oscillation
    assert p.C[0].tolist() == [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]  # sensors on the heated and the far node


def test_two_mass_matches_the_equations_of_motion_held_by_scipy():
    """A, B == scipy's zero-order hold of the equations of motion written out mass by mass; Q == quadrature
    of the disturbance forces' covariance; C reads the two positions."""
    fam = family("two-mass", "two_mass.py", dt=0.3)
    p = fam.sample(12, generator=generator(4))
    q, dt = fam.config.disturbance_std, fam.config.dt
    for s in range(12):
        (m1, m2), (k1, k2), (c1, c2) = (v[s].tolist() for v in (p.mass, p.spring, p.damper))
        A_c = np.zeros((4, 4))
        A_c[0, 2] = A_c[1, 3] = 1.0
        A_c[2] = [-(k1 + k2) / m1, k2 / m1, -(c1 + c2) / m1, c2 / m1]  # m1 a1 = -k1 p1 + k2 (p2 - p1) ...
        A_c[3] = [k2 / m2, -k2 / m2, c2 / m2, -c2 / m2]
        b = np.array([[0.0], [0.0], [1 / m1], [0.0]])
        A, B, *_ = cont2discrete((A_c, b, np.eye(4), np.zeros((4, 1))), dt, method="zoh")
        np.testing.assert_allclose(p.A[s].numpy(), A, rtol=0, atol=1e-12)
        np.testing.assert_allclose(p.B[s].numpy(), B, rtol=1e-10, atol=1e-14)
        G = q * np.array([[0, 0], [0, 0], [1 / m1, 0], [0, 1 / m2]])
        Q, _ = quad_vec(
            lambda t, A_c=A_c, G=G: expm(A_c * t) @ G @ G.T @ expm(A_c * t).T, 0, dt, epsrel=1e-12
        )
        np.testing.assert_allclose(p.Q[s].numpy(), Q, rtol=1e-8, atol=1e-14)
    assert p.C[0].tolist() == [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]]
    assert torch.linalg.eigvals(p.A).abs().max() < 1  # damped: stable


def test_dead_time_plant_matches_its_transfer_function():
    """The augmented model's impulse response from u == that of K (z - z0) / ((z - p1)(z - p2)) z^-d
    (scipy.signal.dimpulse of the transfer function), and its DC gain is 1."""
    fam = family("dead-time", "dead_time.py")
    p = fam.sample(12, generator=generator(2))
    assert set(p.delay.tolist()) <= {1, 2, 3}
    for s in range(12):
        r, th, z0, d = (float(v[s]) for v in (p.radius, p.angle, p.zero, p.delay))
        poles = [r * np.exp(1j * th), r * np.exp(-1j * th)]
        den = np.real(np.poly(poles))
        K = float(np.real((1 - poles[0]) * (1 - poles[1]))) / (1 - z0)
        den = np.concatenate([den, np.zeros(int(d))])  # z^-d: d more powers of z below
        _, (h,) = dimpulse((K * np.array([1.0, -z0]), den, 1), n=21)
        A, B, C = (v[s].numpy() for v in (p.A, p.B, p.C))
        mine = [(C @ np.linalg.matrix_power(A, j) @ B).item() for j in range(20)]  # y_{j+1} from u_0 = 1
        np.testing.assert_allclose(mine, h[1:21, 0], rtol=1e-9, atol=1e-12)
        assert (C @ np.linalg.solve(np.eye(A.shape[0]) - A, B)).item() == pytest.approx(1.0, rel=1e-9)
        assert z0 > 1  # non-minimum phase


@pytest.mark.parametrize(
    ("name", "plugin"),
    [("thermal-network", "thermal_network.py"), ("dead-time", "dead_time.py"), ("two-mass", "two_mass.py")],
)
def test_kalman_innovations_are_white_with_the_filters_variance(name, plugin):
    """On 3000 simulated systems (T = 40) the KF's normalized innovations have E[e_t^2] = 1 per step (0.12,
    about 4.5 standard errors), overall (0.03) and no lag-1..2 correlation (0.025): simulate and
    state_space describe the same model."""
    traj = family(name, plugin).generate(3000, 40, generator=generator(3))
    mean, var = make_predictor("kalman").predict_distribution(traj)
    e = ((traj.y - mean) / var.sqrt()).numpy()
    assert np.abs((e**2).mean(0) - 1).max() < 0.12
    assert np.abs((e**2).mean((0, 1)) - 1).max() < 0.03
    for k in (1, 2):
        lagged = np.einsum("bti,btj->ij", e[:, k:], e[:, :-k]) / (e.shape[0] * (e.shape[1] - k))
        assert np.abs(lagged).max() < 0.025, (k, lagged)


@pytest.mark.parametrize("toml", ["thermal_network.toml", "dead_time.toml", "two_mass.toml"])
def test_experiment_file_end_to_end(tmp_path, tiny_smoke, toml):
    out = tmp_path / "out"
    assert (
        cli.main(["reproduce", str(EXAMPLES / toml), "--preset", "smoke", "--out", str(out), "--quiet"]) == 0
    )
    data = json.loads((out / "eval.json").read_text())
    assert {"mop", "kalman", "arx", "n4sid-kf", "last", "zero"} <= set(data["predictors"])
    kf, last = (data["predictors"][k]["window_error"] for k in ("kalman", "last"))
    assert all(kf[w] < last[w] for w in kf)  # the optimal filter beats repeating the last output
    assert data["settings"]["features"] == "none, 3 steps"  # smoke: no auto
