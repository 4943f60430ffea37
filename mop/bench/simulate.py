"""`mop bench simulate`: systems generated per second, batched mop vs a per-system numpy loop
like the authors' code.

Both sample the systems and simulate one trajectory of T = 50 steps each. The loop is timed on fewer systems
(it is linear in their number) and reported per second. mop: best of 5 runs after a full-size warm-up
(run-to-run spread on a shared 2-core machine is about +-20%).
"""

from __future__ import annotations

import argparse
import json
import math
import time

import numpy as np
import torch

from mop.config import SystemConfig
from mop.systems import generator, make_family
from mop.systems.quadrotor import BOUNDS, GRAVITY, TAU

HORIZON = 50


def loop_linear(num_systems: int, rng: np.random.Generator, n: int = 10, m: int = 5) -> list:
    """One system at a time: A scaled to rho 0.95, C redrawn until observable, then a step-by-step loop."""
    out = []
    for _ in range(num_systems):
        A = rng.uniform(0, 1, (n, n))
        A *= 0.95 / np.abs(np.linalg.eigvals(A)).max()
        while True:
            C = rng.uniform(0, 1, (m, n))
            O = np.vstack([C @ np.linalg.matrix_power(A, k) for k in range(n)])
            if np.linalg.matrix_rank(O) == n:
                break
        x, ys = rng.normal(size=n), []
        for _ in range(HORIZON + 1):
            ys.append(C @ x + 0.1 * rng.normal(size=m))
            x = A @ x + 0.1 * rng.normal(size=n)
        out.append(np.array(ys))
    return out


def loop_quadrotor(num_systems: int, rng: np.random.Generator) -> list:
    """One system at a time, the paper's equations with numpy scalars."""
    bound = np.array(BOUNDS)
    out = []
    for _ in range(num_systems):
        mass, length, inertia = rng.uniform(0.5, 2, 3)
        C = rng.uniform(0, 1, (3, 6))
        s, ys = np.zeros(6), []
        for _ in range(HORIZON + 1):
            ys.append(C @ s + 0.1 * rng.normal(size=3))
            u0, u1 = rng.uniform(-0.5, 0.5, 2)
            px, pz, phi, vx, vz, dphi = s
            s = np.array(
                [
                    px + (vx * math.cos(phi) - vz * math.sin(phi)) * TAU,
                    pz + (vx * math.sin(phi) + vz * math.cos(phi)) * TAU,
                    phi + dphi * TAU,
                    vx + (vz * dphi - GRAVITY * math.sin(phi)) * TAU,
                    vz + (-vx * dphi - GRAVITY * math.cos(phi) + (u0 + u1) / mass) * TAU,
                    (u0 - u1) * length * TAU / inertia,
                ]
            ) + 0.1 * rng.normal(size=6)
            s = np.clip(s, -bound, bound)
        out.append(np.array(ys))
    return out


def measure(family_name: str, num_systems: int, loop_systems: int, repeats: int = 5) -> dict[str, float]:
    family = make_family(SystemConfig(family=family_name), torch.float32)
    family.generate(num_systems, HORIZON, generator=generator(0))  # warm-up at full size (allocator, caches)
    best = math.inf
    for r in range(repeats):
        start = time.perf_counter()
        family.generate(num_systems, HORIZON, generator=generator(r))
        best = min(best, time.perf_counter() - start)
    loop = loop_quadrotor if family_name == "quadrotor" else loop_linear
    start = time.perf_counter()
    loop(loop_systems, np.random.default_rng(0))
    loop_rate = loop_systems / (time.perf_counter() - start)
    rate = num_systems / best
    return {
        "systems": num_systems,
        "loop_systems": loop_systems,
        "systems_per_s": rate,
        "loop_systems_per_s": loop_rate,
        "speedup": rate / loop_rate,
    }


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--systems", type=int, default=20000, help="systems per batched run (20000)")
    parser.add_argument("--loop-systems", type=int, default=500, help="systems for the per-system loop (500)")


def run(args: argparse.Namespace) -> int:
    results = {name: measure(name, args.systems, args.loop_systems) for name in ("linear", "quadrotor")}
    results["torch_threads"] = torch.get_num_threads()
    if args.json:
        print(json.dumps(results, indent=2))
        return 0
    print(f"generate systems, T={HORIZON}, float32, {results['torch_threads']} torch threads (best of 5)")
    print(f"{'family':<10} {'mop systems/s':>14} {'loop systems/s':>15} {'speedup':>8}")
    for name in ("linear", "quadrotor"):
        r = results[name]
        print(
            f"{name:<10} {r['systems_per_s']:>14,.0f} {r['loop_systems_per_s']:>15,.0f} {r['speedup']:>7.0f}x"
        )
    return 0
