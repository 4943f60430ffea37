"""`mop bench filters`: batched mop filters vs a plain per-system loop, on 1000 test systems, T = 50.

KF (linear family) vs filterpy's KalmanFilter per system; RLS-AR(2) vs a per-system numpy RLS loop; the
quadrotor EKF vs a per-system numpy EKF loop; also the N4SID-KF (subspace identification) when available.
Batched runs are timed best of `repeats`; loops run on --loop-systems systems and are scaled to --systems.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections.abc import Callable

import numpy as np
import torch
from torch import Tensor

from mop.config import SystemConfig
from mop.errors import MopError, require
from mop.filters.ekf import EKFPredictor
from mop.filters.kalman import KalmanPredictor
from mop.filters.rls import RLSPredictor
from mop.filters.subspace import N4SIDKalmanPredictor
from mop.systems import generator, make_family
from mop.systems.base import Trajectories
from mop.systems.quadrotor import BOUNDS, GRAVITY, TAU

HORIZON = 50


def best_time(fn: Callable[[], object], repeats: int) -> float:
    fn()  # warm-up
    best = math.inf
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def loop_kalman(traj: Trajectories) -> np.ndarray:
    """filterpy KalmanFilter, one system at a time."""
    from filterpy.kalman import KalmanFilter

    p, y = traj.params.map(Tensor.numpy), traj.y.numpy()
    out = np.zeros_like(y)
    for b in range(y.shape[0]):
        kf = KalmanFilter(dim_x=p.A.shape[-1], dim_z=y.shape[-1])
        kf.F, kf.H, kf.Q, kf.R, kf.P = p.A[b], p.C[b], p.Q[b], p.R[b], p.P0[b].copy()
        for t in range(y.shape[1]):
            out[b, t] = kf.H @ kf.x[:, 0]
            kf.update(y[b, t])
            kf.predict()
    return out


def loop_rls(traj: Trajectories, order: int = 2) -> np.ndarray:
    """Per system: numpy matrix RLS-AR(order) (every output on all outputs at `order` lags), P0 = I,
    yhat_0 = 0 and yhat_t = y_{t-1} until order + 1 outputs are seen (the paper's baseline)."""
    y = traj.y.numpy()
    B, T, m = y.shape
    out = np.zeros_like(y)

    def phi(z: np.ndarray, t: int) -> np.ndarray:  # [z_t, z_{t-1}, ..., z_{t-order+1}], zero before z_0
        return np.concatenate([z[t - j] if t - j >= 0 else np.zeros(m) for j in range(order)])

    for b in range(B):
        z, theta, P = y[b], np.zeros((order * m, m)), np.eye(order * m)
        out[b, 1 : order + 1] = z[: min(order, T - 1)]
        for t in range(order + 1, T):
            f = phi(z, t - 2)
            k = P @ f / (1 + f @ P @ f)
            theta, P = theta + np.outer(k, z[t - 1] - theta.T @ f), P - np.outer(k, f @ P)
            out[b, t] = theta.T @ phi(z, t - 1)
    return out


def quad_f(
    x: np.ndarray, u: np.ndarray, mass: float, length: float, inertia: float
) -> tuple[np.ndarray, np.ndarray]:
    """Quadrotor step f(x, u) and its Jacobian df/dx, numpy scalars (as mop.systems.quadrotor)."""
    _, _, phi, vx, vz, dphi = x
    c, s = math.cos(phi), math.sin(phi)
    f = x + TAU * np.array(
        [
            vx * c - vz * s,
            vx * s + vz * c,
            dphi,
            vz * dphi - GRAVITY * s,
            -vx * dphi - GRAVITY * c + (u[0] + u[1]) / mass,
            0.0,
        ]
    )
    f[5] = dphi + (u[0] - u[1]) * length * TAU / inertia  # the angular rate accumulates
    F = np.eye(6)
    F[0, 2:5] = TAU * np.array([-vx * s - vz * c, c, -s])
    F[1, 2:5] = TAU * np.array([vx * c - vz * s, s, c])
    F[2, 5] = TAU
    F[3, [2, 4, 5]] = TAU * np.array([-GRAVITY * c, dphi, vz])
    F[4, [2, 3, 5]] = TAU * np.array([GRAVITY * s, -dphi, -vx])
    return f, F


def loop_ekf(traj: Trajectories) -> np.ndarray:
    """Per-system numpy EKF (the authors' style): the posterior mean is clipped before the step, the
    predicted mean after it, F taken at the unclipped posterior."""
    p, y, u = traj.params.map(Tensor.numpy), traj.y.numpy(), traj.u.numpy()
    out, bound = np.zeros_like(y), np.array(BOUNDS)
    for b in range(y.shape[0]):
        C, Q, R, P = p.C[b], p.Q[b], p.R[b], p.P0[b].copy()
        m = np.clip(p.x0_mean[b], -bound, bound)
        for t in range(y.shape[1]):
            out[b, t] = C @ m
            S = C @ P @ C.T + R
            K = np.linalg.solve(S, C @ P).T
            m = m + K @ (y[b, t] - C @ m)
            I_KC = np.eye(6) - K @ C
            P = I_KC @ P @ I_KC.T + K @ R @ K.T
            mlJ = (p.mass[b], p.length[b], p.inertia[b])
            _, F = quad_f(m, u[b, t], *mlJ)
            f, _ = quad_f(np.clip(m, -bound, bound), u[b, t], *mlJ)
            m, P = np.clip(f, -bound, bound), F @ P @ F.T + Q
    return out


def measure(
    name: str, predictor, loop: Callable | None, traj: Trajectories, loop_systems: int, repeats: int
) -> dict:
    seconds = best_time(lambda: predictor.predict(traj), repeats)
    row = {"seconds": seconds, "systems": traj.num_systems}
    if loop is not None:
        small = traj.select(slice(0, loop_systems))
        start = time.perf_counter()
        ref = loop(small)
        row["loop_seconds"] = (time.perf_counter() - start) * traj.num_systems / loop_systems
        row["speedup"] = row["loop_seconds"] / seconds
        row["max_abs_diff_vs_loop"] = float(np.abs(predictor.predict(small).numpy() - ref).max())
    return row


def _ekf_predictor():
    return EKFPredictor()


def _n4sid_predictor():
    return N4SIDKalmanPredictor()


def run_all(num_systems: int, loop_systems: int, repeats: int) -> dict:
    linear = make_family(SystemConfig(family="linear"), torch.float64).generate(
        num_systems, HORIZON, generator=generator(0)
    )
    quad = make_family(SystemConfig(family="quadrotor"), torch.float64).generate(
        num_systems, HORIZON, generator=generator(1)
    )
    results = {
        "kalman": measure("kalman", KalmanPredictor(), loop_kalman, linear, loop_systems, repeats),
        "rls": measure("rls", RLSPredictor(), loop_rls, linear, loop_systems, repeats),
        "ekf": measure("ekf", _ekf_predictor(), loop_ekf, quad, loop_systems, repeats),
    }
    n4sid = _n4sid_predictor()
    if n4sid is not None:
        results["n4sid-kf"] = measure("n4sid-kf", n4sid, None, linear, loop_systems, 1)
    results["total_seconds_kf_rls_ekf"] = sum(results[k]["seconds"] for k in ("kalman", "rls", "ekf"))
    results["total_loop_seconds_kf_rls_ekf"] = sum(
        results[k]["loop_seconds"] for k in ("kalman", "rls", "ekf")
    )
    results["torch_threads"] = torch.get_num_threads()
    results["horizon"] = HORIZON
    return results


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--systems", type=int, default=1000, help="test systems (1000)")
    parser.add_argument(
        "--loop-systems",
        type=int,
        default=200,
        help="systems for the per-system loops, scaled to --systems (200)",
    )
    parser.add_argument("--repeats", type=int, default=3, help="batched runs, best of (3)")


def run(args: argparse.Namespace) -> int:
    require("filterpy", "mop bench filters (the per-system reference loop)")

    if args.systems < 1 or not 1 <= args.loop_systems <= args.systems or args.repeats < 1:
        raise MopError("bench filters: need --systems >= 1, 1 <= --loop-systems <= --systems, --repeats >= 1")
    results = run_all(args.systems, args.loop_systems, args.repeats)
    if args.json:
        print(json.dumps(results, indent=2))
        return 0
    print(
        f"filters over {args.systems} systems, T={HORIZON}, float64, "
        f"{results['torch_threads']} torch threads "
        f"(loops on {args.loop_systems} systems, scaled)"
    )
    print(f"{'predictor':<10} {'mop s':>9} {'loop s':>9} {'speedup':>8} {'max |diff|':>11}")
    for name in ("kalman", "rls", "ekf", "n4sid-kf"):
        if name in results:
            r = results[name]
            loop = (
                f"{r['loop_seconds']:>9.3f} {r['speedup']:>7.0f}x {r['max_abs_diff_vs_loop']:>11.1e}"
                if "loop_seconds" in r
                else f"{'-':>9} {'-':>8} {'-':>11}"
            )
            print(f"{name:<10} {r['seconds']:>9.3f} {loop}")
    print(
        f"KF + RLS + EKF: {results['total_seconds_kf_rls_ekf']:.3f} s "
        f"(loops {results['total_loop_seconds_kf_rls_ekf']:.1f} s)"
    )
    return 0
