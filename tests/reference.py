"""Slow, independent reference implementations used only by the tests, in one place: a per-system filterpy
Kalman filter, the authors' quadrotor step written coordinate by coordinate in numpy, and seeded batches
(a learned model's forecasts and simulation by definition: tests/reference_models.py)."""

import copy
import csv
import importlib.util
import math
from pathlib import Path

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


def filterpy_forecast(A, C, Q, R, y, x0, P0, steps, B=None, u=None):
    """k-step forecasts (B, T, K, m) by filterpy: at each t, a copy of the filter before its update at t is
    advanced j times by KalmanFilter.predict(u=u_{t+i}) (no measurement); [:, t, j] = H x then, NaN where
    t + j >= T. Arrays (B, ...)."""
    Bn, T, m = y.shape
    out = np.full((Bn, T, steps, m), np.nan)
    for b in range(Bn):
        kf = KalmanFilter(dim_x=A.shape[-1], dim_z=C.shape[1], dim_u=0 if B is None else B.shape[-1])
        kf.F, kf.H, kf.Q, kf.R, kf.x, kf.P = A[b], C[b], Q[b], R[b], x0[b].copy(), P0[b].copy()
        if B is not None:
            kf.B = B[b]
        for t in range(T):
            ahead = copy.deepcopy(kf)
            for j in range(min(steps, T - t)):
                out[b, t, j] = C[b] @ ahead.x
                ahead.predict(u=None if u is None else u[b, t + j])
            kf.update(y[b, t])
            kf.predict(u=None if u is None else u[b, t])
    return out


def monte_carlo_bias(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """(estimate of the squared bias, its standard error) of a Monte Carlo method from two runs with
    independent draws, each given minus the exact answer: a, b (S, ...) over S independent systems.

    Where the method is unbiased, a and b are independent errors of mean 0, so E[a b] = 0; a bias d makes
    E[a b] = d^2 (the Monte Carlo noise cancels, unlike in (a)^2). The standard error comes from the
    spread of the S per-system means of a b."""
    per_system = (a * b).reshape(a.shape[0], -1).mean(1)
    return float(per_system.mean()), float(per_system.std(ddof=1) / np.sqrt(len(per_system)))


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
    p = traj.params.map(torch.Tensor.numpy)
    y = traj.y.numpy()
    x0 = np.zeros((y.shape[0], p.A.shape[-1]))
    return filterpy_predict(p.A, p.C, p.Q, p.R, y, x0, p.P0)


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


def interrupted_and_resumed(config, out_dir: Path, monkeypatch, step: int = 4) -> Path:
    """Train `config` into out_dir with a SIGINT during training step `step` (the run stops there, with the
    one-line message), then again to the end (a resume from its checkpoint); the run directory."""
    import pytest

    import mop.train as mt
    from mop.errors import MopError

    restore = sigint_during_step(monkeypatch, step)
    with pytest.raises(MopError, match=f"stopped by SIGINT at step {step}"):
        mt.train(config, out_dir, progress=False)
    restore()
    return mt.train(config, out_dir, progress=False)


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


def filterpy_predict_gaps(A, C, Q, R, y, x0, P0):
    """filterpy_predict for y with NaN: a step with every channel missing is update(None) (filterpy skips it);
    a step with some channels missing conditions on the measured ones through filterpy's update with the
    rows H_o and the block R_oo passed per step."""
    out = np.zeros_like(y)
    for b in range(A.shape[0]):
        kf = KalmanFilter(dim_x=A.shape[-1], dim_z=C.shape[1])
        kf.F, kf.H, kf.Q, kf.R, kf.x, kf.P = A[b], C[b], Q[b], R[b], x0[b].copy(), P0[b].copy()
        for t in range(y.shape[1]):
            out[b, t] = C[b] @ kf.x
            seen = ~np.isnan(y[b, t])
            if not seen.any():
                kf.update(None)
            else:
                kf.update(y[b, t, seen], R=R[b][np.ix_(seen, seen)], H=C[b][seen])
            kf.predict()
    return out


def filterpy_distribution_gaps(A, C, Q, R, y, x0, P0):
    """filterpy_predict_gaps with the predictive covariances: (mean (B, T, m), S (B, T, m, m)) where
    S_t = H P_t H^T + R of filterpy's prior P_t before its update at t, i.e. of the whole y_t, after earlier
    steps were skipped (update(None)) or conditioned on their measured channels only."""
    Bn, T, m = y.shape
    mean, S = np.zeros_like(y), np.zeros((Bn, T, m, m))
    for b in range(Bn):
        kf = KalmanFilter(dim_x=A.shape[-1], dim_z=m)
        kf.F, kf.H, kf.Q, kf.R, kf.x, kf.P = A[b], C[b], Q[b], R[b], x0[b].copy(), P0[b].copy()
        for t in range(T):
            mean[b, t], S[b, t] = C[b] @ kf.x, C[b] @ kf.P @ C[b].T + R[b]
            seen = ~np.isnan(y[b, t])
            if not seen.any():
                kf.update(None)
            else:
                kf.update(y[b, t, seen], R=R[b][np.ix_(seen, seen)], H=C[b][seen])
            kf.predict()
    return mean, S


def joint_gaussian_predict(A, C, Q, R, P0, y):
    """E[y_t | the measured entries of y_0..y_{t-1}] by brute force, one system: every y_t is linear in
    xi = (x_0, w_0..w_{T-1}, v_0..v_T) (zero mean), so the outputs are jointly Gaussian with covariance
    G Cov(xi) G^T; condition on the observed (non-NaN) entries of the past. A (n, n), C (m, n), Q, R, P0,
    y (T+1, m) -> (T+1, m)."""
    n, m, T1 = A.shape[0], C.shape[0], y.shape[0]
    dim = n * T1 + m * T1  # x_0, w_0..w_{T-1} (n each), v_0..v_T (m each)
    G = np.zeros((T1 * m, dim))
    for t in range(T1):
        # x_t = A^t x_0 + sum_{i<t} A^{t-1-i} w_i
        for i in range(t + 1):
            block = np.linalg.matrix_power(A, t - i)  # i = 0 is x_0 (A^t); i >= 1 is w_{i-1}: A^{t-i}
            G[t * m : (t + 1) * m, i * n : (i + 1) * n] = C @ block
        G[t * m : (t + 1) * m, n * T1 + t * m : n * T1 + (t + 1) * m] = np.eye(m)
    cov_xi = scipy_block_diag(P0, *[Q] * (T1 - 1), *[R] * T1)
    S = G @ cov_xi @ G.T  # (T1 m, T1 m)
    flat = y.reshape(-1)
    out = np.zeros((T1, m))
    for t in range(T1):
        past = np.arange(t * m)
        o = past[~np.isnan(flat[past])]
        target = np.arange(t * m, (t + 1) * m)
        if len(o):
            out[t] = S[np.ix_(target, o)] @ np.linalg.solve(S[np.ix_(o, o)], flat[o])
    return out


def scipy_block_diag(*blocks):
    from scipy.linalg import block_diag

    return block_diag(*blocks)


def rls_gaps_reference(y, order=2, u=None, input_order=2):
    """The RLS-AR(order) predictor with missing outputs, by batch ridge regression, one system, numpy:
    theta_i(t) = (I + sum phi phi^T)^{-1} sum phi y_{s,i} over the pairs (phi_{s-1}, y_s), s < t, whose target
    y_{s,i} and whole regressor phi_{s-1} = [y_{s-1}; ...; y_{s-p}] (zero before y_0) were measured;
    yhat_t = theta(t)^T phi~_{t-1}, phi~ with each missing entry replaced by its own prediction;
    yhat_0 = 0, yhat_t = y~_{t-1} for t <= p. y (T, m) with NaN -> (T, m). With inputs u (T, k) (ARX):
    phi also holds [u_{s-1}; ...; u_{s-q}] (q = input_order) and the start-up runs to r = max(p, q)."""
    T, m = y.shape
    filled, preds = np.zeros_like(y), np.zeros_like(y)
    r = order if u is None else max(order, input_order)

    def lagged(values, s):
        ys = [values[s - j] if s - j >= 0 else np.zeros(m) for j in range(order)]
        if u is None:
            return np.concatenate(ys)
        us = [u[s - j] if s - j >= 0 else np.zeros(u.shape[1]) for j in range(input_order)]
        return np.concatenate(ys + us)

    d = len(lagged(y, 0))
    for t in range(T):
        if t == 0:
            pred = np.zeros(m)
        elif t <= r:
            pred = filled[t - 1]
        else:
            pred = np.zeros(m)
            for i in range(m):
                G, b = np.eye(d), np.zeros(d)
                for s in range(r, t):
                    phi = lagged(y, s - 1)
                    if np.isnan(y[s, i]) or np.isnan(phi).any():
                        continue
                    G += np.outer(phi, phi)
                    b += phi * y[s, i]
                pred[i] = np.linalg.solve(G, b) @ lagged(filled, t - 1)
        preds[t] = pred
        filled[t] = np.where(np.isnan(y[t]), pred, y[t])
    return preds


def load_example(path: Path, name: str):
    """Import an examples/ script by its path (examples are not a package) as module `name`."""
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def run_example_smoke(module, out: Path) -> list:
    """`module.main(["--out", out, "--budget", "smoke"])` on one torch thread (restored after): its rows."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return module.main(["--out", str(out), "--budget", "smoke"])
    finally:
        torch.set_num_threads(threads)
