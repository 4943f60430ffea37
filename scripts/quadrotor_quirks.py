"""How much do the three quirks of the authors' quadrotor code that mop does not copy move the EKF's error?

    PYTHONPATH=. python scripts/quadrotor_quirks.py [--num-systems 1000] [--seed 7000001]

mop follows the paper's text in three places where the authors' released code differs (DESIGN.md):
  (a) ekf-noise: their EKF adds a random N(0, 0.01 I) draw to its predicted mean: clip(f(clip(m), u) + w);
  (b) x0-shared: their x_0 copies ONE N(0, 1) draw into all six coordinates (then clip);
  (c) v-shared:  one observation-noise draw per step is shared by the three outputs.
The quirks live only in this script. Each is switched on alone, then all three together (the authors' setup),
on the same systems, actions and noise draws. Printed: mop's EKF's error (averaged over 3 seeds of the
filter's own draws where (a) is on), its change from the quirk-free row, ekf-noclip's and last value's errors;
error = mean over systems of ||yhat_t - y_t||_2 averaged over t in [20, 50), float64.
"""

from __future__ import annotations

import argparse
import itertools

import torch

from mop.config import SystemConfig
from mop.filters.ekf import ekf_predict
from mop.filters.gaussian import condition_on
from mop.systems import generator, make_family
from mop.systems.linear import normal, uniform
from mop.systems.quadrotor import ACTION_RANGE, QuadrotorFamily, clip_state, dynamics

HORIZON, WINDOW, NOISE_DRAWS = 50, (20, 50), 3


def simulate(params, horizon, gen, *, x0_shared=False, v_shared=False, sigma=0.1, x0_std=1.0):
    """QuadrotorFamily.simulate (same draws, same order) with quirks (b) and (c) switchable."""
    B = params.C.shape[0]
    u = uniform((B, horizon + 1, 2), *ACTION_RANGE, gen)  # (B, T+1, 2)
    w = normal((B, horizon, 6), gen) * sigma
    v = normal((B, horizon + 1, 3), gen) * sigma
    e0 = normal((B, 6), gen)
    if x0_shared:
        e0 = e0[:, :1].expand(B, 6)  # one draw copied into all six coordinates
    if v_shared:
        v = v[..., :1].expand(B, horizon + 1, 3)  # one draw shared by the three outputs
    x = clip_state(params.x0_mean + e0 * x0_std)
    xs = [x]
    for t in range(horizon):
        x = clip_state(dynamics(x, u[:, t], params.mass, params.length, params.inertia) + w[:, t])
        xs.append(x)
    x = torch.stack(xs, dim=1)  # (B, T+1, 6)
    return x @ params.C.mT + v, u


def ekf_with_noisy_mean(params, y, u, gen, sigma=0.1):
    """mop's EKF with quirk (a): m <- clip(f(clip(m), u) + w), w ~ N(0, sigma^2 I) drawn by the filter."""
    model = QuadrotorFamily.state_space(params)
    C, Q, R, P = params.C, params.Q, params.R, params.P0
    m, preds = clip_state(model.m0), []
    for t in range(y.shape[1]):
        preds.append((C @ m[..., None])[..., 0])
        m, P, _ = condition_on(m, P, y[:, t], C, R)
        F = model.jacobian(m, u[:, t], t)  # at the unclipped posterior mean, as mop's EKF and theirs
        m = model.f(clip_state(m)[:, None], u[:, t, None], t)[:, 0]
        m, P = clip_state(m + normal(m.shape, gen) * sigma), F @ P @ F.mT + Q
    return torch.stack(preds, dim=1)


def window_error(yhat, y):
    return float((yhat - y).norm(dim=-1)[:, WINDOW[0] : WINDOW[1]].mean())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--num-systems", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=7000001)
    args = ap.parse_args()
    family = make_family(SystemConfig(family="quadrotor"), torch.float64)
    params = family.sample(args.num_systems, generator=generator(args.seed))
    # sanity: with no quirk the script's simulator is mop's, draw for draw
    ref = family.simulate(params, HORIZON, generator=generator(args.seed + 1))
    y0, _ = simulate(params, HORIZON, generator(args.seed + 1))
    assert torch.equal(ref.y, y0), "script simulator drifted from QuadrotorFamily.simulate"
    print(f"N = {args.num_systems}, seed {args.seed}, error over t in [{WINDOW[0]},{WINDOW[1]})")
    print("x0-shared v-shared ekf-noise |    ekf change ekf-noclip   last")
    base = None
    for x0_shared, v_shared, ekf_noise in itertools.product((False, True), repeat=3):
        y, u = simulate(params, HORIZON, generator(args.seed + 1), x0_shared=x0_shared, v_shared=v_shared)
        if ekf_noise:  # the filter's own draws: mean over NOISE_DRAWS seeds
            ekf = sum(
                window_error(ekf_with_noisy_mean(params, y, u, generator(args.seed + 2 + k)), y)
                for k in range(NOISE_DRAWS)
            )
            ekf /= NOISE_DRAWS
        else:
            ekf = window_error(ekf_predict(QuadrotorFamily.state_space(params), y, u), y)
        base = ekf if base is None else base
        noclip = ekf_predict(QuadrotorFamily.state_space(params), y, u, project=False)
        last = torch.cat([torch.zeros_like(y[:, :1]), y[:, :-1]], dim=1)  # yhat_t = y_{t-1}
        row = (ekf, ekf - base, window_error(noclip, y), window_error(last, y))
        on = ((x0_shared, 9), (v_shared, 8), (ekf_noise, 9))
        flags = [f"{'yes' if q else '-':>{width}}" for q, width in on]
        print(f"{' '.join(flags)} | {row[0]:6.3f} {row[1]:+6.3f} {row[2]:10.3f} {row[3]:6.3f}")


if __name__ == "__main__":
    main()
