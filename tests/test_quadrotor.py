"""Quadrotor family against a plain per-system numpy implementation of the authors' equations."""

import math

import numpy as np
import torch

from mop.config import SystemConfig
from mop.systems import generator, make_family
from mop.systems.quadrotor import BOUNDS, dynamics, dynamics_jacobian
from tests.reference import numpy_clip, numpy_quadrotor_step, quad_traj


def test_dynamics_matches_numpy_on_random_states():
    """Unclipped f against the authors' equations at random states, actions and (m, l, J)."""
    rng = np.random.default_rng(0)
    x, u, mlJ = rng.normal(size=(50, 6)) * 2, rng.uniform(-0.5, 0.5, (50, 2)), rng.uniform(0.5, 2, (3, 50))
    got = dynamics(*(torch.from_numpy(a) for a in (x, u, *mlJ))).numpy()
    ref = np.stack([numpy_quadrotor_step(x[b], u[b], *mlJ[:, b]) for b in range(50)])
    np.testing.assert_allclose(got, ref, atol=1e-12)


def test_noise_free_trajectory_matches_numpy_loop():
    traj = quad_traj(10, 40, 0, noise_var_w=0.0, noise_var_v=0.0)
    p = traj.params.map(torch.Tensor.numpy)
    u, x, y = traj.u.numpy(), traj.x.numpy(), traj.y.numpy()
    for b in range(10):
        s = x[b, 0]
        for t in range(41):
            np.testing.assert_allclose(x[b, t], s, atol=1e-10)
            np.testing.assert_allclose(y[b, t], p.C[b] @ s, atol=1e-10)
            s = numpy_clip(numpy_quadrotor_step(s, u[b, t], p.mass[b], p.length[b], p.inertia[b]))


def test_angular_rate_accumulates_in_simulated_trajectories():
    """x[t+1, phidot] = clip(phidot_t + (u0 - u1) l tau / J + w_t): the residual is w (std 0.1) where the clip
    is inactive. Without phidot_t the residual would be phidot_t itself (std ~0.5)."""
    traj = quad_traj(500, 50, 6)
    p, x, u = traj.params, traj.x, traj.u
    drive = (u[:, :-1, 0] - u[:, :-1, 1]) * (p.length * 0.1 / p.inertia)[:, None]  # (B, T)
    resid = x[:, 1:, 5] - (x[:, :-1, 5] + drive)
    inside = x[:, 1:, 5].abs() < BOUNDS[5] - 1e-9
    assert inside.float().mean() > 0.3
    np.testing.assert_allclose(resid[inside].std().item(), 0.1, rtol=0.05)
    assert resid[inside].mean().abs() < 0.01


def test_initial_state_is_clipped_unit_normal_per_coordinate():
    """x_0 = clip(N(0, 1)) independently per coordinate. For Z ~ N(0,1) and bound b:
    P(|clip Z| = b) = 2 (1 - Phi(b)), E clip(Z)^2 = (2 Phi(b) - 1) - 2 b phi(b) + 2 b^2 (1 - Phi(b)).
    N = 20000 draws: tolerance 0.015 on the fraction at the bound (4 sd) and 0.03 on the std (3 sd)."""
    fam = make_family(SystemConfig(family="quadrotor"), torch.float64)
    params = fam.sample(20000, generator=generator(7))
    x0 = fam.simulate(params, 1, generator=generator(8)).x[:, 0].numpy()  # (N, 6)
    Phi = lambda z: 0.5 * (1 + math.erf(z / math.sqrt(2)))  # noqa: E731
    pdf = lambda z: math.exp(-z * z / 2) / math.sqrt(2 * math.pi)  # noqa: E731
    for i, b in enumerate(BOUNDS):
        at_bound = (np.abs(x0[:, i]) >= b - 1e-12).mean()
        second = (2 * Phi(b) - 1) - 2 * b * pdf(b) + 2 * b * b * (1 - Phi(b))
        assert abs(at_bound - 2 * (1 - Phi(b))) < 0.015, (i, at_bound)
        assert abs(x0[:, i].std() - math.sqrt(second)) < 0.03, (i, x0[:, i].std())
    corr = np.corrcoef(x0.T)[np.triu_indices(6, 1)]
    assert np.abs(corr).max() < 0.05  # independent (the authors' code copies one draw into all six)
    np.testing.assert_allclose(params.P0[0].numpy(), np.eye(6))
    assert (params.x0_mean == 0).all()


def test_x0_std_scales_the_initial_state():
    fam = make_family(SystemConfig(family="quadrotor", x0_std=0.2), torch.float64)
    params = fam.sample(5000, generator=generator(9))
    x0 = fam.simulate(params, 1, generator=generator(10)).x[:, 0]
    np.testing.assert_allclose(x0.std(0).numpy(), 0.2, rtol=0.05)  # bounds >= pi/4 = 3.9 sd barely bite
    np.testing.assert_allclose(params.P0[0].numpy(), 0.04 * np.eye(6))


def test_parameter_and_input_ranges_and_clipping():
    traj = quad_traj(500, 50, 1)
    for v in (traj.params.mass, traj.params.length, traj.params.inertia):
        assert v.min() >= 0.5 and v.max() <= 2.0 and v.max() - v.min() > 1.3
    assert traj.u.abs().max() <= 0.5 and traj.u.shape == (500, 51, 2)
    assert ((traj.params.C >= 0) & (traj.params.C <= 1)).all()
    bound = torch.tensor(BOUNDS, dtype=torch.float64)
    assert (traj.x.abs() <= bound).all()
    assert (traj.x.abs() >= bound * 0.999).any()  # the clip is actually hit (the drone falls: thrust < g)
    np.testing.assert_allclose(traj.params.R[0].numpy(), 0.01 * np.eye(3))


def test_observation_noise_std_and_independence():
    traj = quad_traj(1000, 20, 2)
    v = (traj.y - traj.x @ traj.params.C.mT).reshape(-1, 3).numpy()
    np.testing.assert_allclose(v.std(0), 0.1, rtol=0.02)
    corr = np.corrcoef(v.T)[np.triu_indices(3, 1)]
    assert np.abs(corr).max() < 0.02  # one draw per output (the authors' code shares one among the three)


def test_jacobian_matches_autograd():
    g = torch.Generator().manual_seed(3)
    x = torch.randn(8, 6, generator=g, dtype=torch.float64) * 2
    u = torch.rand(8, 2, generator=g, dtype=torch.float64) - 0.5
    m, l, J = torch.rand(3, 8, generator=g, dtype=torch.float64) * 1.5 + 0.5
    F = dynamics_jacobian(x, u, m, l, J)
    for b in range(8):
        args = (u[b], m[b], l[b], J[b])
        ref = torch.autograd.functional.jacobian(lambda s, args=args: dynamics(s, *args), x[b])
        torch.testing.assert_close(F[b], ref)
