"""The cascaded-tanks family against independent references: scipy's solve_ivp on the continuous physics, the
closed-form equilibria (with and without overflow), autograd for the Jacobian, numpy's FFT for the input's
band, and the particle filter that knows each plant against the last value."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.integrate import solve_ivp

from mop import cli
from mop.config import SystemConfig
from mop.errors import MopError
from mop.predictors import forecast, make_predictor
from mop.systems import generator, make_family
from mop.systems.cascaded_tanks import PHYSICS, TS, simulate_levels, tank_jacobian, tank_step, unit_rms_signal

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def tanks(num_systems, horizon, seed, **knobs):
    family = make_family(SystemConfig(family="cascaded-tanks", **knobs), torch.float64)
    return family.generate(num_systems, horizon, generator=generator(seed))


def numpy_rhs(h, u, p):
    """A1 dh1/dt = k_p u - a1 sqrt(h1), A2 dh2/dt = a1 sqrt(h1) - a2 sqrt(h2) (levels below the rims)."""
    q1, q2 = p["outflow1"] * np.sqrt(max(h[0], 0.0)), p["outflow2"] * np.sqrt(max(h[1], 0.0))
    return [(p["pump"] * u - q1) / p["area1"], (q1 - q2) / p["area2"]]


def test_discretisation_matches_solve_ivp_without_overflow():
    """The RK4 map (2 substeps of 2 s) against solve_ivp (rtol 1e-10) over 100 samples of 4 s, u held over
    each sample, on noise-free records that never reach a rim; measured 1.5e-6 V over 300 samples."""
    traj = tanks(12, 100, 1, noise_std=0.0, process_noise_std=0.0)
    H = traj.params.max_level[:, None]
    below = (traj.x < H[..., None] - 1e-6).all(-1).all(-1)
    assert int(below.sum()) >= 6
    for b in below.nonzero()[:, 0].tolist():
        p = {k: float(v[b]) for k, v in traj.params.as_dict().items() if k in PHYSICS}
        h, u = traj.x[b, 0].numpy(), traj.u[b, :, 0].numpy()
        levels = [h]
        for t in range(traj.horizon):
            sol = solve_ivp(
                lambda _, z, ut=u[t], p=p: numpy_rhs(z, ut, p), (0, TS), h, rtol=1e-10, atol=1e-12
            )
            h = sol.y[:, -1]
            levels.append(h)
        np.testing.assert_allclose(traj.x[b].numpy(), np.array(levels), atol=1e-4)


def test_equilibrium_equals_closed_form_with_and_without_overflow():
    """After 2000 samples (> 30 time constants) of a constant u: h1 = (k_p u / a1)^2, h2 = (k_p u / a2)^2
    below the rims; when k_p u > a1 sqrt(H) the upper tank stays at H and the lower one receives
    a1 sqrt(H) + rho (k_p u - a1 sqrt(H)), so h2 = (that / a2)^2 (clipped at H)."""
    family = make_family(SystemConfig(family="cascaded-tanks"), torch.float64)
    p = family.sample(64, generator=generator(2)).as_dict()  # the physics helpers take a dict
    H = p["max_level"]
    u_fill = p["outflow1"] * H.sqrt() / p["pump"]  # the input that just fills the upper tank
    u_below = torch.minimum(u_fill, p["outflow2"] * H.sqrt() / p["pump"])  # neither tank reaches H
    for u in (0.3 * u_below, 0.6 * u_below, 0.9 * u_below, 1.3 * u_fill, 2.0 * u_fill):
        u = u[:, None, None]
        x = simulate_levels(torch.zeros(64, 2, dtype=torch.float64), u.expand(64, 2001, 1), p)[:, -1]
        inflow = p["pump"] * u[:, 0, 0]
        through = torch.minimum(inflow, p["outflow1"] * H.sqrt())
        h1 = torch.minimum((inflow / p["outflow1"]) ** 2, H)
        h2 = torch.minimum(((through + p["overflow_to_lower"] * (inflow - through)) / p["outflow2"]) ** 2, H)
        np.testing.assert_allclose(x.numpy(), torch.stack([h1, h2], -1).numpy(), rtol=1e-6, atol=1e-9)
        assert bool((x[:, 0] < H).all()) if bool((u[:, 0, 0] < u_fill).all()) else bool((x[:, 0] == H).all())


def test_levels_stay_within_the_rims_and_the_upper_tank_overflows_at_its_maximum():
    """Noisy records: 0 <= h <= H always (the clip, after the noise too), some records reach H exactly, and
    the overflow carries water: with rho = 0 the lower tank ends lower than with rho > 0."""
    traj = tanks(200, 300, 3, input_amplitude=0.8)
    H = traj.params.max_level[:, None, None]
    assert bool((traj.x >= 0).all()) and bool((traj.x <= H).all())
    full = (traj.x[..., 0] == H[..., 0]).any(1)
    assert 0.05 < full.double().mean() < 0.9  # some overflow, not all
    family = make_family(SystemConfig(family="cascaded-tanks"), torch.float64)
    p = family.sample(8, generator=generator(4)).as_dict()  # the physics helpers take a dict
    u = (3 * p["outflow1"] * p["max_level"].sqrt() / p["pump"])[:, None, None].expand(8, 301, 1)
    spilling = simulate_levels(torch.zeros(8, 2, dtype=torch.float64), u, p)[:, -1]
    dry = simulate_levels(
        torch.zeros(8, 2, dtype=torch.float64), u, {**p, "overflow_to_lower": 0 * u[:, 0, 0]}
    )
    assert bool((spilling[:, 0] == p["max_level"]).all())
    short = dry[:, -1, 1] < p["max_level"] - 1e-3  # lower tanks that do not fill without the spill
    assert int(short.sum()) >= 2 and bool((dry[:, -1, 1] <= spilling[:, 1]).all())
    assert bool((dry[short, -1, 1] < spilling[short, 1] - 1e-3).all())


def test_jacobian_equals_central_differences_inside_at_the_rim_and_near_empty():
    """df/dx against (f(x + e) - f(x - e)) / 2e, e = 1e-6, at states inside, just below the upper rim while
    filling (it overflows within the step: its row is 0) and near empty, at u and 4 u (more overflow)."""
    traj = tanks(16, 20, 5)
    p = {k: v for k, v in traj.params.as_dict().items() if k in PHYSICS}
    u, H, eps = traj.u[:, 3], p["max_level"], 1e-6
    states = {
        "inside": torch.minimum(traj.x[:, 3], H[:, None] - 0.01),  # at H exactly f has a kink
        "upper just below the rim": torch.stack([H - 1e-3, traj.x[:, 3, 1]], -1),
        "near empty": torch.full((16, 2), 0.05, dtype=torch.float64),
    }
    for name, x in states.items():
        for v in (u, 4 * u):
            J = tank_jacobian(x, v, p)
            for j in range(2):
                e = torch.zeros(2, dtype=torch.float64)
                e[j] = eps
                fd = (tank_step(x + e, v, p) - tank_step(x - e, v, p)) / (2 * eps)
                np.testing.assert_allclose(J[:, :, j].numpy(), fd.numpy(), atol=1e-6, err_msg=name)


def test_same_seed_same_numbers_other_seed_other_numbers():
    for kind in ("multisine", "white", "prbs"):
        a, b, c = (tanks(4, 30, s, input=kind) for s in (0, 0, 1))
        for name in ("y", "u", "x"):
            assert torch.equal(getattr(a, name), getattr(b, name))
            assert not torch.allclose(getattr(a, name), getattr(c, name))
        pairs = zip(a.params.as_dict().values(), b.params.as_dict().values(), strict=True)
        assert all(torch.equal(u, v) for u, v in pairs)


def test_multisine_has_unit_rms_and_no_power_above_its_band():
    """numpy's FFT of the excitation: power only on lines 1..floor(bandwidth T), RMS 1, mean 0."""
    band = torch.tensor([0.02, 0.05, 0.1, 0.3], dtype=torch.float64)
    s = unit_rms_signal("multisine", {"bandwidth": band}, 400, generator(0)).numpy()
    np.testing.assert_allclose(np.sqrt((s**2).mean(1)), 1.0, rtol=1e-12)
    power = np.abs(np.fft.rfft(s, axis=1)) ** 2
    for b, f in enumerate(band.tolist()):
        K = int(np.floor(f * 400))
        assert power[b, 0] < 1e-12 and np.all(power[b, K + 1 :] < 1e-12) and np.all(power[b, 1 : K + 1] > 1)


def test_particle_filter_knowing_the_plant_beats_the_last_value():
    """One-step MSE over t >= 50 on 24 plants of 150 steps (measured ratio 0.44); the UKF and EKF run on
    the same StateSpace; the PF's simulation (one roll-out) equals its forecast from that origin."""
    traj = tanks(24, 150, 6)
    err = {n: ((make_predictor(n).predict(traj) - traj.y)[:, 50:] ** 2).mean().item() for n in ("pf", "last")}
    assert err["pf"] < 0.6 * err["last"], err
    for name in ("ukf", "ekf"):
        assert ((make_predictor(name).predict(traj) - traj.y)[:, 50:] ** 2).mean().item() < 0.6 * err["last"]
    pf, short = make_predictor("pf"), traj.select(slice(0, 4))
    np.testing.assert_array_equal(pf.simulate(short, 140).numpy(), forecast(pf, short, 11)[:, 140].numpy())


@pytest.mark.parametrize(
    "knob, value",
    [
        ("input", "sine"),
        ("noise_std", -1.0),
        ("x0", "full"),
        ("bandwidth", 0.7),
        ("input_amplitude", 0.0),
        ("sensor_saturation", 1.0),
    ],
)
def test_bad_knobs_are_refused_in_one_line_naming_the_value(knob, value):
    with pytest.raises(MopError, match=f"system.{knob}") as err:
        SystemConfig(family="cascaded-tanks", **{knob: value})
    assert str(value) in str(err.value) and "\n" not in str(err.value)


def test_a_saturating_sensor_reads_the_same_plant_clipped_at_its_top():
    """system.sensor_saturation = 0.2: the plants are those drawn without it (its top S is drawn last), S is
    within [0.8 H, H], and the output is the unsaturated one clipped at S, flat there on some plants."""
    B, T = 40, 600
    plain = make_family(SystemConfig(family="cascaded-tanks", input_amplitude=1.0), torch.float64)
    saturating = make_family(
        SystemConfig(family="cascaded-tanks", input_amplitude=1.0, sensor_saturation=0.2), torch.float64
    )
    params, same = saturating.sample(B, generator=generator(3)), plain.sample(B, generator=generator(3))
    for name in (*PHYSICS, "u_op", "amplitude", "bandwidth", "noise_std", "x0_mean"):
        torch.testing.assert_close(getattr(params, name), getattr(same, name), rtol=0, atol=0)
    assert torch.isinf(same.sensor_top).all()
    H, S = params.max_level, params.sensor_top
    assert ((S >= 0.8 * H) & (S <= H)).all() and (S < H).all()
    clipped = saturating.simulate(params, T, generator=generator(4))
    free = plain.simulate(params, T, generator=generator(4))
    torch.testing.assert_close(clipped.x, free.x, rtol=0, atol=0)
    torch.testing.assert_close(clipped.y, torch.minimum(free.y, S[:, None, None]), rtol=0, atol=0)
    at_top = (clipped.y[..., 0] == S[:, None]).double().mean(1)  # (B,) share of samples at the top
    assert 5 <= int((at_top > 0.01).sum()) < B


def test_steady_start_is_at_rest_under_the_operating_input():
    """x0="steady": x_0 is the equilibrium at u_op, so the levels do not move while u stays at u_op."""
    traj = tanks(8, 5, 9, x0="steady", noise_std=0.0, process_noise_std=0.0)
    p = traj.params
    np.testing.assert_allclose(traj.x[:, 0].numpy(), p.x0_mean.numpy(), atol=1e-12)
    x = simulate_levels(traj.x[:, 0], p.u_op[:, None, None].expand(8, 50, 1), p.as_dict())
    np.testing.assert_allclose(x.numpy(), traj.x[:, :1].expand(8, 50, 2).numpy(), atol=1e-10)


def test_experiment_file_end_to_end(tmp_path, tiny_smoke):
    """examples/cascaded_tanks.toml at the smoke preset: MOP, the PF and UKF that know each plant, ARX,
    arx-best and the last value, one-step and simulated; the PF's claim holds."""
    out = tmp_path / "tanks"
    argv = [
        "reproduce",
        str(EXAMPLES / "cascaded_tanks.toml"),
        "--preset",
        "smoke",
        "--out",
        str(out),
        "--quiet",
    ]
    assert cli.main(argv) == 0
    data = json.loads((out / "eval.json").read_text())
    assert data["experiment"] == "cascaded-tanks" and data["num_systems"] == 6 and data["horizon"] == 199
    assert set(data["predictors"]) == {"mop", "pf", "ukf", "arx", "arx-best", "last"}
    simulated = data["conditions"]["test"]["simulation"]["rmse"]
    assert all(np.isfinite(r["simulation_rmse"]) for r in simulated.values()) and len(simulated) == 6
    pf_claim = next(c for c in data["claims"] if c["measure"].startswith("one-step RMSE of pf"))
    assert pf_claim["holds"]


def test_simulation_fast_path_equals_the_filters_step_function():
    """simulate_levels (numpy, the training data's path) against x_{t+1} = clip(tank_step(x_t, u_t) + w_t)
    run in torch with the tank_step the filters are given, on plants that overflow (input swings up to the
    pump's range) and with process noise: equal to float rounding."""
    family = make_family(SystemConfig(family="cascaded-tanks", input_amplitude=1.0), torch.float64)
    g = generator(6)
    p = family.sample(32, generator=g).as_dict()
    u = (p["u_op"][:, None] * (1 + torch.randn(32, 301, generator=g, dtype=torch.float64))).clamp(0, 10)
    w = 0.05 * torch.randn(32, 300, 2, generator=g, dtype=torch.float64)
    x = [p["x0_mean"]]
    phys = {k: p[k] for k in PHYSICS}
    for t in range(300):
        x.append(
            torch.minimum(
                (tank_step(x[-1], u[:, t, None], phys) + w[:, t]).clamp(min=0), p["max_level"][:, None]
            )
        )
    want = torch.stack(x, 1)
    got = simulate_levels(p["x0_mean"], u[..., None], p, w)
    assert bool((want[..., 0] == p["max_level"][:, None]).any())  # some overflow
    torch.testing.assert_close(got, want, rtol=1e-12, atol=1e-12)
