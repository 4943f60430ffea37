"""Quadrotor family against a plain per-system numpy implementation of the paper's equations."""

import math

import numpy as np
import torch

from mop.config import SystemConfig
from mop.systems import generator, make_family
from mop.systems.quadrotor import BOUNDS, dynamics, dynamics_jacobian


def numpy_step(s, u, mass, length, inertia, tau=0.1, g=10.0):
    px, pz, phi, vx, vz, dphi = s
    return np.array(
        [
            px + (vx * math.cos(phi) - vz * math.sin(phi)) * tau,
            pz + (vx * math.sin(phi) + vz * math.cos(phi)) * tau,
            phi + dphi * tau,
            vx + (vz * dphi - g * math.sin(phi)) * tau,
            vz + (-vx * dphi - g * math.cos(phi) + (u[0] + u[1]) / mass) * tau,
            dphi + (u[0] - u[1]) * length * tau / inertia,
        ]
    )


def test_noise_free_trajectory_matches_numpy_loop():
    fam = make_family(
        SystemConfig(family="quadrotor", noise_var_w=0.0, noise_var_v=0.0, x0_std=0.0), torch.float64
    )
    traj = fam.generate(10, 40, generator=generator(0))
    p = {k: v.numpy() for k, v in traj.params.items()}
    u, y = traj.u.numpy(), traj.y.numpy()
    for b in range(10):
        s = p["x0_mean"][b]
        for t in range(41):
            np.testing.assert_allclose(y[b, t], p["C"][b] @ s, atol=1e-10)
            s = np.clip(
                numpy_step(s, u[b, t], p["mass"][b], p["length"][b], p["inertia"][b]),
                -np.array(BOUNDS),
                np.array(BOUNDS),
            )


def test_parameter_and_input_ranges_and_clipping():
    traj = make_family(SystemConfig(family="quadrotor"), torch.float64).generate(
        500, 50, generator=generator(1)
    )
    for name in ("mass", "length", "inertia"):
        v = traj.params[name]
        assert v.min() >= 0.5 and v.max() <= 2.0 and v.max() - v.min() > 1.3
    assert traj.u.abs().max() <= 0.5 and traj.u.shape == (500, 51, 2)
    assert ((traj.params["C"] >= 0) & (traj.params["C"] <= 1)).all()
    bound = torch.tensor(BOUNDS, dtype=torch.float64)
    assert (traj.x.abs() <= bound).all()
    assert (traj.x.abs() >= bound * 0.999).any()  # the clip is actually hit (the drone falls: thrust < g)
    np.testing.assert_allclose(traj.params["R"][0].numpy(), 0.01 * np.eye(3))


def test_observation_noise_std():
    traj = make_family(SystemConfig(family="quadrotor"), torch.float64).generate(
        1000, 20, generator=generator(2)
    )
    v = (traj.y - traj.x @ traj.params["C"].mT).reshape(-1).numpy()
    np.testing.assert_allclose(v.std(), 0.1, rtol=0.02)


def test_jacobian_matches_autograd():
    g = torch.Generator().manual_seed(3)
    x = torch.randn(4, 6, generator=g, dtype=torch.float64)
    u = torch.rand(4, 2, generator=g, dtype=torch.float64) - 0.5
    m, l, J = torch.rand(3, 4, generator=g, dtype=torch.float64) + 0.5
    F = dynamics_jacobian(x, u, m, l, J)
    for b in range(4):
        args = (u[b], m[b], l[b], J[b])
        ref = torch.autograd.functional.jacobian(lambda s, args=args: dynamics(s, *args), x[b])
        torch.testing.assert_close(F[b], ref)


def test_dynamics_matches_numpy_on_random_states():
    """Unclipped f against the paper's equations at random states (the clip masks vz on trajectories)."""
    rng = np.random.default_rng(0)
    x, u, mlJ = rng.normal(size=(20, 6)), rng.uniform(-0.5, 0.5, (20, 2)), rng.uniform(0.5, 2, (3, 20))
    got = dynamics(*(torch.from_numpy(a) for a in (x, u, *mlJ))).numpy()
    ref = np.stack([numpy_step(x[b], u[b], *mlJ[:, b]) for b in range(20)])
    np.testing.assert_allclose(got, ref, atol=1e-12)
