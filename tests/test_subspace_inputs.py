"""N4SID with inputs: the Markov parameters C A^j B it identifies against nfoursid's (PO-MOESP) and the
truth, and n4sid-kf using the inputs where the data has them."""

import numpy as np
import pandas as pd
import pytest
import torch
from nfoursid.nfoursid import NFourSID

from mop.config import SystemConfig
from mop.filters.subspace import identify_with_inputs, n4sid_kalman_predict
from mop.predictors import make_predictor
from mop.systems import generator, make_family


def markov(A, B, C, num=6):
    """[C B, C A B, ..., C A^{num-1} B]: invariant under a change of state basis."""
    out, AjB = [], B
    for _ in range(num):
        out.append(C @ AjB)
        AjB = A @ AjB
    return np.stack(out)


def simulate(seed, n=3, m=2, k=2, N=800, noise=0.0):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n))
    A *= 0.8 / np.abs(np.linalg.eigvals(A)).max()
    B, C = rng.normal(size=(n, k)), rng.normal(size=(m, n))
    u, x, ys = rng.normal(size=(N, k)), np.zeros(n), []
    for t in range(N):
        ys.append(C @ x + noise * rng.normal(size=m))
        x = A @ x + B @ u[t] + noise * rng.normal(size=n)
    return A, B, C, np.array(ys), u


def nfoursid_markov(y, u, order, i):
    df = pd.DataFrame(np.concatenate([y, u], axis=1))
    df.columns = [f"y{j}" for j in range(y.shape[1])] + [f"u{j}" for j in range(u.shape[1])]
    sid = NFourSID(
        df,
        output_columns=list(df.columns[: y.shape[1]]),
        input_columns=list(df.columns[y.shape[1] :]),
        num_block_rows=i,
    )
    sid.subspace_identification()
    ss, _ = sid.system_identification(rank=order)
    return markov(ss.a, ss.b, ss.c)


@pytest.mark.parametrize("seed", [0, 1])
def test_noise_free_markov_parameters_equal_nfoursid_and_the_truth(seed):
    A, B, C, y, u = simulate(seed)
    ours = identify_with_inputs(torch.from_numpy(y)[None], torch.from_numpy(u)[None], 3, 4, ridge=0.0)
    A_hat, B_hat, C_hat, _ = (M[0].numpy() for M in ours)
    truth = markov(A, B, C)
    np.testing.assert_allclose(markov(A_hat, B_hat, C_hat), truth, atol=1e-7)
    np.testing.assert_allclose(nfoursid_markov(y, u, 3, 4), truth, atol=1e-7)


def test_noisy_markov_parameters_agree_with_nfoursid():
    A, B, C, y, u = simulate(2, N=4000, noise=0.1)
    ours = identify_with_inputs(torch.from_numpy(y)[None], torch.from_numpy(u)[None], 3, 4)
    mine = markov(*(M[0].numpy() for M in ours[:3]))
    ref = nfoursid_markov(y, u, 3, 4)
    scale = np.abs(markov(A, B, C)).max()
    assert np.abs(mine - ref).max() < 0.05 * scale
    assert np.abs(mine - markov(A, B, C)).max() < 0.05 * scale


def test_n4sid_kf_uses_the_inputs():
    traj = make_family(
        SystemConfig(family="linear-inputs", state_dim=4, output_dim=2, input_dim=1), torch.float64
    ).generate(40, 60, generator=generator(4))
    with_u = make_predictor("n4sid-kf").predict(traj)
    without = n4sid_kalman_predict(traj.y, 4)
    mse = lambda yhat: float(((yhat - traj.y) ** 2)[:, 30:].mean())  # noqa: E731
    assert mse(with_u) < 0.3 * mse(without)
    assert mse(with_u) < 1.5 * mse(make_predictor("kalman").predict(traj))
