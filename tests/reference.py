"""Slow, independent reference implementations used only by the tests, in one place: a per-system filterpy
Kalman filter, the authors' quadrotor step written coordinate by coordinate in numpy, and seeded batches."""

import csv
import math

import numpy as np
import torch
from filterpy.kalman import KalmanFilter

from mop.config import SystemConfig
from mop.systems import generator, make_family
from mop.systems.quadrotor import BOUNDS


def filterpy_predict(A, C, Q, R, y, x0, P0):
    """One filterpy KalmanFilter per system; predictions H x before each update. Arrays (B, ...)."""
    out = np.zeros_like(y)
    for b in range(A.shape[0]):
        kf = KalmanFilter(dim_x=A.shape[-1], dim_z=C.shape[1])
        kf.F, kf.H, kf.Q, kf.R, kf.x, kf.P = A[b], C[b], Q[b], R[b], x0[b].copy(), P0[b].copy()
        for t in range(y.shape[1]):
            out[b, t] = C[b] @ kf.x
            kf.update(y[b, t])
            kf.predict()
    return out


def filterpy_on(traj) -> np.ndarray:
    """filterpy_predict on a linear family's Trajectories (x_0 mean 0)."""
    p = {k: v.numpy() for k, v in traj.params.items()}
    y = traj.y.numpy()
    x0 = np.zeros((y.shape[0], p["A"].shape[-1]))
    return filterpy_predict(p["A"], p["C"], p["Q"], p["R"], y, x0, p["P0"])


def numpy_quadrotor_step(s, u, mass, length, inertia, tau=0.1, g=10.0):
    """One Euler step of the authors' code, coordinate by coordinate (phidot accumulates)."""
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


def numpy_clip(s):
    return np.array([min(max(si, -b), b) for si, b in zip(s, BOUNDS, strict=True)])


def quad_traj(num_systems, horizon, seed, **kw):
    """Seeded quadrotor trajectories in float64."""
    return make_family(SystemConfig(family="quadrotor", **kw), torch.float64).generate(
        num_systems, horizon, generator=generator(seed)
    )


def linear_traj(num_systems=6, horizon=30, seed=0, **kw):
    """Seeded small linear trajectories (n = 4, m = 2) in float64."""
    return make_family(
        SystemConfig(family="linear", state_dim=4, output_dim=2, **kw), torch.float64
    ).generate(num_systems, horizon, generator=generator(seed))


def write_long_csv(path, ys) -> None:
    """Trajectories ys [(T_i+1, 2)] as the long CSV `trajectory,t,y0,y1` (names r0, r1, ...)."""
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["trajectory", "t", "y0", "y1"])
        for i, y in enumerate(ys):
            for t, row in enumerate(y):
                w.writerow([f"r{i}", t, *row])


def read_long_csv(path) -> dict:
    """{trajectory: array of the value columns after `trajectory,t`} from a long CSV mop writes."""
    out = {}
    with open(path) as f:
        for r in list(csv.reader(f))[1:]:
            out.setdefault(r[0], []).append([float(v) for v in r[2:]])
    return {k: np.array(v) for k, v in out.items()}


def sigint_during_step(monkeypatch, step: int):
    """Make TrainingData.batch send SIGINT to this process while it prepares training step `step` (as a
    Ctrl-C arriving then); returns a function that restores the real batch."""
    import os
    import signal

    import mop.train as mt

    batch, calls = mt.TrainingData.batch, []

    def interrupting_batch(self):
        calls.append(1)
        if len(calls) == step:
            os.kill(os.getpid(), signal.SIGINT)
        return batch(self)

    monkeypatch.setattr(mt.TrainingData, "batch", interrupting_batch)
    return lambda: monkeypatch.setattr(mt.TrainingData, "batch", batch)


def authors_linear_systems(num_systems, seed, n=10, m=5, horizon=50, noise_std=0.1, bound=50.0):
    """The authors' linear generator, one system at a time in numpy (DESIGN.md): A ~ U[0,1]^(n x n) scaled to
    spectral radius 0.95; C ~ U[0,1]^(m x n) redrawn until (A, C) is observable; x_0 ~ N(0, I);
    w_t, v_t ~ N(0, noise_std^2 I); a trajectory with any |x| or |y| > bound is redrawn. Returns A (B, n, n),
    C (B, m, n), y (B, horizon + 1, m), independent of mop's generator (numpy's PCG64, not torch)."""
    rng = np.random.default_rng(seed)
    As, Cs, ys = [], [], []
    while len(ys) < num_systems:
        A = rng.uniform(0, 1, (n, n))
        A *= 0.95 / np.abs(np.linalg.eigvals(A)).max()
        while True:
            C = rng.uniform(0, 1, (m, n))
            obs = np.vstack([C @ np.linalg.matrix_power(A, k) for k in range(n)])
            if np.linalg.matrix_rank(obs) == n:
                break
        x = rng.standard_normal(n)
        y = np.zeros((horizon + 1, m))
        ok = True
        for t in range(horizon + 1):
            y[t] = C @ x + noise_std * rng.standard_normal(m)
            ok = ok and np.abs(x).max() <= bound and np.abs(y[t]).max() <= bound
            x = A @ x + noise_std * rng.standard_normal(n)
        if ok:
            As.append(A), Cs.append(C), ys.append(y)
    return np.stack(As), np.stack(Cs), np.stack(ys)
