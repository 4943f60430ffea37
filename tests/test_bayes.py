"""The Bayes mixture over a family (mop.filters.bayes) against a brute-force reference: each drawn system's
Kalman filter (mop.filters.kalman, tested against filterpy), its likelihood by scipy, the weights by
scipy.special.softmax."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.special import softmax
from scipy.stats import multivariate_normal

from mop.config import SystemConfig
from mop.errors import MopError, MopWarning
from mop.experiments import evaluating, run_config  # evaluating.test_*: not collected as tests
from mop.experiments.files import load_experiment
from mop.filters.bayes import bank_sums, bayes_mixture, draw_bank
from mop.filters.kalman import KalmanPredictor, kalman_filter
from mop.filters.linear_gaussian import linear_systems
from mop.metrics import mse_ratio_ci
from mop.predictors import forecast, make_predictor, nan_beyond_horizon
from mop.systems import generator, make_family

ROOT = Path(__file__).resolve().parents[1]  # the child imports this checkout of mop
SYSTEM = SystemConfig(family="linear-inputs", state_dim=2, output_dim=2, input_dim=1)


def _reference(bank, y, u):
    """(yhat (N, T+1, m), ess (N, T+1)) by brute force, one drawn system and one trajectory at a time."""
    M, (N, T1, m) = bank.A.shape[0], y.shape
    preds, logliks = np.zeros((M, N, T1, m)), np.zeros((M, N, T1))
    for j in range(M):
        rep = [bank.A, bank.C, bank.Q, bank.R]
        A, C, Q, R = (x[j : j + 1].expand(N, *x.shape[1:]) for x in rep)
        x0, P0 = bank.m0[j].expand(N, -1), bank.P0[j].expand(N, -1, -1)
        out = kalman_filter(A, C, Q, R, y, x0, P0, bank.B[j].expand(N, -1, -1), u)
        preds[j] = out.yhat.numpy()
        for i in range(N):
            for t in range(1, T1):
                e = y[i, t - 1].numpy()
                cov = out.S[i, t - 1].numpy()
                mean = out.yhat[i, t - 1].numpy()
                logliks[j, i, t] = logliks[j, i, t - 1] + multivariate_normal.logpdf(e, mean, cov)
    w = softmax(logliks, axis=0)  # (M, N, T+1)
    return (w[..., None] * preds).sum(0), 1 / (w**2).sum(0)


def test_mixture_equals_brute_force_bayes():
    bank = draw_bank(SYSTEM, 5, seed=3)
    traj = make_family(SYSTEM, torch.float64).generate(4, 12, generator=generator(8))
    f, ess = bayes_mixture(bank, traj.y, traj.u, chunk=2)  # chunks of 2, 2, 1 combined
    yhat = f[:, :, 0]
    ref_yhat, ref_ess = _reference(bank, traj.y, traj.u)
    np.testing.assert_allclose(yhat.numpy(), ref_yhat, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(ess.numpy(), ref_ess, rtol=1e-8)
    assert float(ess[:, 0].min()) == pytest.approx(5.0)  # no data yet: the prior's equal weights


def test_shards_combine_to_the_bank_of_their_union():
    """scripts/bayes_bank.py runs a bank as shards in separate processes and adds their BankSums: the sum
    is the union's mixture, against the brute-force reference, whatever the split."""
    bank = draw_bank(SYSTEM, 7, seed=5)
    traj = make_family(SYSTEM, torch.float64).generate(3, 10, generator=generator(9))
    ref_yhat, ref_ess = _reference(bank, traj.y, traj.u)
    for split in (1, 4, 6):
        sums = bank_sums(bank[split:], traj.y, traj.u) + bank_sums(bank[:split], traj.y, traj.u)
        np.testing.assert_allclose(sums.mean[:, :, 0].numpy(), ref_yhat, rtol=1e-8, atol=1e-10)
        np.testing.assert_allclose(sums.ess.numpy(), ref_ess, rtol=1e-8)


def test_a_bank_of_the_true_system_is_its_kalman_filter():
    family = make_family(SYSTEM, torch.float64)
    traj = family.generate(1, 20, generator=generator(2))
    one = linear_systems(family.state_space(traj.params), 1)
    bank = type(one)(*(None if v is None else v.expand(3, *v.shape[1:]) for v in vars(one).values()))
    many = family.simulate(
        traj.params.__class__(**{k: v.expand(6, *v.shape[1:]) for k, v in vars(traj.params).items()}),
        20,
        generator=generator(4),
    )
    f, ess = bayes_mixture(bank, many.y, many.u, steps=4)
    kf = KalmanPredictor()
    torch.testing.assert_close(f[:, :, 0], kf.predict(many), rtol=1e-9, atol=1e-9)
    ref = forecast(kf, many, 4)  # the KF's own roll-out with the future inputs
    torch.testing.assert_close(nan_beyond_horizon(f.clone()), ref, rtol=1e-9, atol=1e-9, equal_nan=True)
    torch.testing.assert_close(ess, torch.full_like(ess, 3.0))


def test_predictor_takes_the_family_from_the_experiment():
    """On a family of three unknown numbers (a, b, c) the bank covers the posterior (large ESS), so the
    mixture is near the Bayes predictor: well below ARX, above the filter that knows the system."""
    small = SystemConfig(family="linear-inputs", state_dim=1, output_dim=1, input_dim=1)
    traj = make_family(small, torch.float64).generate(64, 30, generator=generator(1))
    bayes = make_predictor("bayes", shared={"seed": 0, "system": small}, bank_size=2000)
    err = (bayes.predict(traj) - traj.y)[:, 10:].pow(2).mean()
    kf = (KalmanPredictor().predict(traj) - traj.y)[:, 10:].pow(2).mean()
    arx = (make_predictor("arx").predict(traj) - traj.y)[:, 10:].pow(2).mean()
    assert kf < err < 0.8 * arx, (kf, err, arx)
    assert float(bayes.ess[:, 30].median()) > 20
    with pytest.raises(MopError, match="needs the family"):
        make_predictor("bayes", shared={"seed": 0})


def test_a_collapsed_bank_is_said():
    """linear-inputs draws whole matrices: 50 systems cannot cover its posterior; the predictor says so."""
    traj = make_family(SYSTEM, torch.float64).generate(8, 30, generator=generator(1))
    with pytest.warns(MopWarning, match="effective sample size"):
        make_predictor("bayes", shared={"system": SYSTEM}, bank_size=50).predict(traj)


def test_bank_script_first_shard_is_the_reports_bayes_row(tmp_path):
    """scripts/bayes_bank.py's first row is the `bayes` predictor at bank_size SIZE (seed 0) on the test
    systems the experiment's report evaluates (smoke preset: N = 32); then one row per added shard."""
    experiment, out = ROOT / "examples" / "two_mass.toml", tmp_path / "bank.json"
    args = ["--shards", "2", "--size", "40", "--jobs", "1", "--preset", "smoke", "--out", str(out)]
    script = [sys.executable, str(ROOT / "scripts" / "bayes_bank.py"), str(experiment), *args]
    r = subprocess.run(script, capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    rows = json.loads(out.read_text())["rows"]
    exp = load_experiment(experiment)
    trained = run_config(exp, "smoke", 0)
    system = evaluating.test_system(trained, exp.conditions[0])
    traj = evaluating.test_trajectories(system, 32, trained.train.horizon, 0)
    error = lambda yhat: (yhat.double() - traj.y).norm(dim=-1).numpy()  # noqa: E731
    bayes = make_predictor("bayes", system=system, bank_size=40, seed=0).predict(traj)
    ratio = mse_ratio_ci(error(bayes), error(KalmanPredictor().predict(traj)), 20, traj.horizon + 1)[0]
    assert [row["systems"] for row in rows] == [40, 80]
    assert rows[0]["ratio"] == pytest.approx(ratio, rel=1e-9)


def test_bank_script_refuses_a_family_without_a_linear_gaussian_model_in_one_line():
    """The pendulum is nonlinear: no bank of Kalman filters, said in one line before any shard runs."""
    script = [
        sys.executable,
        str(ROOT / "scripts" / "bayes_bank.py"),
        str(ROOT / "examples" / "pendulum.toml"),
    ]
    r = subprocess.run([*script, "--preset", "smoke"], capture_output=True, text=True, cwd=ROOT)
    assert r.returncode != 0 and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and r.stderr.startswith("bayes_bank: "), r.stderr
