"""Slow, independent reference implementations used only by the tests, in one place: a per-system filterpy
Kalman filter, the authors' quadrotor step written coordinate by coordinate in numpy, and seeded batches."""

import csv
import math

import numpy as np
import scipy.linalg
import torch
from filterpy.kalman import KalmanFilter

from mop.config import SystemConfig
from mop.systems import generator, make_family
from mop.systems.quadrotor import BOUNDS


def filterpy_predict(A, C, Q, R, y, x0, P0, B=None, u=None):
    """One filterpy KalmanFilter per system; predictions H x before each update, then predict(u=u_t) with the
    input matrix B where given. Arrays (B, ...)."""
    out = np.zeros_like(y)
    for b in range(A.shape[0]):
        kf = KalmanFilter(dim_x=A.shape[-1], dim_z=C.shape[1], dim_u=0 if B is None else B.shape[-1])
        kf.F, kf.H, kf.Q, kf.R, kf.x, kf.P = A[b], C[b], Q[b], R[b], x0[b].copy(), P0[b].copy()
        if B is not None:
            kf.B = B[b]
        for t in range(y.shape[1]):
            out[b, t] = C[b] @ kf.x
            kf.update(y[b, t])
            kf.predict(u=None if u is None else u[b, t])
    return out


def gaussian_conditioning_predict(A, C, Q, R, y, x0, P0, B, u):
    """E[y_t | y_<t] by conditioning the joint Gaussian of (y_0..y_{T-1}) directly (no recursion), one system:
    y = M z + d with z = [x_0 - x0, w_0..w_{T-2}, v_0..v_{T-1}] ~ N(0, blockdiag(P0, Q.., R..)) and d the
    mean driven by x0 and B u. A (n, n), C (m, n), B (n, k), y (T, m), u (T, k)."""
    T, m, n = y.shape[0], C.shape[0], A.shape[0]
    nz = n + (T - 1) * n + T * m
    M, d = np.zeros((T * m, nz)), np.zeros(T * m)
    Gx, mean = np.zeros((n, nz)), x0.copy()  # x_t = Gx z + mean
    Gx[:, :n] = np.eye(n)
    for t in range(T):
        M[t * m : (t + 1) * m] = C @ Gx
        M[t * m : (t + 1) * m, n + (T - 1) * n + t * m : n + (T - 1) * n + (t + 1) * m] = np.eye(m)
        d[t * m : (t + 1) * m] = C @ mean
        if t < T - 1:
            Gx = A @ Gx
            Gx[:, n + t * n : n + (t + 1) * n] += np.eye(n)
            mean = A @ mean + B @ u[t]
    cov_z = scipy.linalg.block_diag(P0, *([Q] * (T - 1)), *([R] * T))
    S = M @ cov_z @ M.T
    flat, out = y.reshape(-1), np.zeros_like(y)
    for t in range(T):
        k = t * m
        gain = np.linalg.solve(S[:k, :k], S[:k, k : k + m]).T if k else np.zeros((m, 0))
        out[t] = d[k : k + m] + gain @ (flat[:k] - d[:k])
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
