"""The duffing family against independent references: scipy's solve_ivp on the continuous oscillator, the
exact zero-order-hold discretisation (scipy.linalg.expm) of its linear part, the torch map the filters use
against the numpy simulation, the input's unit-RMS linear response, and the UKF that knows each oscillator
against the last value."""

import numpy as np
import pytest
import torch
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from mop.config import SystemConfig
from mop.errors import MopError
from mop.predictors import make_predictor
from mop.systems import generator, make_family
from mop.systems.duffing import simulate_states


def oscillators(num_systems, horizon, seed, **knobs):
    family = make_family(SystemConfig(family="duffing", **knobs), torch.float64)
    return family.generate(num_systems, horizon, generator=generator(seed))


def physics(traj, i):
    return {k: float(getattr(traj.params, k)[i]) for k in ("omega", "zeta", "k2", "k3", "gain")}


def test_discretisation_matches_solve_ivp():
    """The RK4 map (8 substeps per sample) against solve_ivp (rtol 1e-10) from each recorded state over one
    sample, u held, on 60 samples of noise-free records with the cubic and quadratic springs on (measured
    up to 3e-5 against the unit RMS of the linear response; with 2 substeps it fails)."""
    traj = oscillators(4, 60, 3, noise_std=0.0)
    for i in range(4):
        p, u, x = physics(traj, i), traj.u[i, :, 0].numpy(), traj.x[i].numpy()

        def rhs(_, s, ut, p=p):
            spring = s[0] + p["k2"] * s[0] ** 2 + p["k3"] * s[0] ** 3
            return [s[1], -2 * p["zeta"] * p["omega"] * s[1] - p["omega"] ** 2 * spring + p["gain"] * ut]

        for t in range(60):
            exact = solve_ivp(rhs, (0, 1), x[t], args=(u[t],), rtol=1e-10, atol=1e-12).y[:, -1]
            np.testing.assert_allclose(x[t + 1], exact, atol=1e-4)


def test_linear_part_is_the_zero_order_hold_discretisation():
    """k2 = k3 = 0: x_{t+1} = A x_t + B u_t with A = expm(F), B = int_0^1 expm(F s) ds g (exact ZOH)."""
    traj = oscillators(3, 80, 5, cubic=0.0, quadratic=0.0, noise_std=0.0)
    for i in range(3):
        p = physics(traj, i)
        F = np.array([[0.0, 1.0], [-(p["omega"] ** 2), -2 * p["zeta"] * p["omega"]]])
        big = np.zeros((3, 3))
        big[:2, :2], big[1, 2] = F, p["gain"]
        E = expm(big)
        A, B = E[:2, :2], E[:2, 2]
        x, u = traj.x[i].numpy(), traj.u[i, :, 0].numpy()
        np.testing.assert_allclose(x[1:], x[:-1] @ A.T + u[:-1, None] * B, atol=1e-5)  # RK4: 1.5e-6


def test_linear_response_has_unit_rms_and_the_torch_map_equals_numpy():
    """The gain makes the linear part's response to the record's input RMS 1 (simulated again here without
    the springs' nonlinear terms); the filters' torch map (state_space.f) steps the numpy simulation."""
    traj = oscillators(6, 300, 11)
    family = make_family(SystemConfig(family="duffing"), torch.float64)
    params = {k: getattr(traj.params, k).numpy() for k in ("omega", "zeta", "k2", "k3", "gain")}
    linear = simulate_states(
        traj.u[..., 0].numpy(), {**params, "k2": 0 * params["k2"], "k3": 0 * params["k3"]}
    )
    np.testing.assert_allclose(np.sqrt((linear[:, :, 0] ** 2).mean(1)), 1.0, rtol=1e-9)
    ss = family.state_space(traj.params)
    stepped = ss.f(traj.x[:, :-1].double(), traj.u[:, :-1].double(), 0)
    np.testing.assert_allclose(stepped.numpy(), traj.x[:, 1:].numpy(), atol=1e-12)


def test_same_seed_same_records_and_inputs_of_each_kind():
    a, b = oscillators(9, 50, 2), oscillators(9, 50, 2)
    assert torch.equal(a.y, b.y) and torch.equal(a.u, b.u)
    assert set(a.params.kind.tolist()) == {0.0, 1.0}  # "mixed": multisines and white noise
    arrow = oscillators(4, 999, 2, input="arrow")
    first, last = arrow.u[:, :200].std(), arrow.u[:, -200:].std()
    assert last > 3 * first  # the arrow's amplitude grows from 0 to sqrt(3)


def test_ukf_that_knows_the_oscillator_beats_the_last_value():
    """Statistical: over 16 noisy oscillators, the UKF's one-step MSE is below a tenth of the last value's."""
    traj = oscillators(16, 200, 4, noise_std=0.05)
    y = traj.y[:, 1:]
    ukf = make_predictor("ukf").predict(traj)[:, 1:]
    last = traj.y[:, :-1]
    assert float(((ukf - y) ** 2).mean()) < 0.1 * float(((last - y) ** 2).mean())


def test_bad_knobs_are_one_line_errors():
    with pytest.raises(MopError, match="omega_low"):
        SystemConfig(family="duffing", omega_high=2.0)
    with pytest.raises(MopError, match="system.input"):
        SystemConfig(family="duffing", input="chirp")
