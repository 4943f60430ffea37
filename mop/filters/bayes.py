"""The Bayes predictor over a family of linear-Gaussian systems: what the best predictor that does not know
the system, only the family it comes from, can reach (an estimate of it, by importance sampling).

A test system is one draw theta ~ p(theta) of its family. The predictor that minimises the expected squared
error given the past and the family alone is the posterior mean

    E[y_t | y_{<t}, u_{<t}] = sum_j w_j(t) yhat_t^(j),   w_j(t) ∝ p(y_{<t} | u_{<t}, theta_j),

over theta_1..theta_M drawn from the family's prior (its sampler, another seed than the test systems):
yhat^(j) and the likelihood are those of system j's Kalman filter (prediction-error decomposition,
p(y_{<t} | theta_j) = prod_{s<t} N(y_s; yhat_s^(j), S_s^(j))). As M -> infinity this is the Bayes-optimal
predictor; with finite M it is still a predictor that reads only the past and the family, so its error is an
achievable one: no predictor trained on the family needs to be worse than it (the effective sample size
1 / sum_j w_j^2, reported by bayes_mixture, says how close to the limit M is). The Kalman filter that knows
the system is below every such predictor; the gap between the two is the price of not knowing the system.

Sampling from the prior works where the family has few unknowns (physical parameters): measured on the
small preset's N = 500 test systems, M = 20000, MSE ratio to the KF over t in [20, 50] (median ESS at t = 50):
rlc-circuit 1.031 (91), thermal-network 1.069 (21), two-mass 1.072 (57), dead-time 1.256 (3.7). A low ESS
means M is too small: grown in shards (BankSums, scripts/bayes_bank.py), dead-time's estimate falls to
1.170 at M = 40000 and settles at 1.136 from M = 160000 to 200000 (ESS 28), while thermal-network's stays
at 1.068 (M = 60000, ESS 50) and two-mass's at 1.071 (M = 80000, ESS 217). Where the family draws whole
random matrices (linear-inputs: 40 unknowns) the weights collapse on one system (ESS 1.0) and the mixture is
far from the limit (6.9, worse than ARX); the predictor warns below a median ESS of LOW_ESS.

Cost: M Kalman filters per test trajectory, O(N M T n^2); the gains, which do not depend on the data, are
computed once per drawn system (2 to 3 min for M = 20000, N = 500, T = 50 on one core). Linear-Gaussian
families whose state space is their exact model (mop.filters.linear_gaussian.family_systems): the built-in
linear families and plugins such as examples/two_mass.py. `mop reproduce FILE --bayes` adds it where an
experiment lists it (the smoke and small presets leave it out unless asked).
"""

from __future__ import annotations

import dataclasses
import math
import warnings

import torch
from torch import Tensor

from mop.config import SystemConfig
from mop.errors import MopError, MopWarning
from mop.filters.linear_gaussian import LinearSystems, family_systems, filter_means, predictor_gains
from mop.predictors import PREDICTORS
from mop.systems import generator, make_family
from mop.systems.base import Trajectories

BANK_SEED_OFFSET = 7_000_003  # the drawn systems: apart from the test, training and validation streams
LOW_ESS = 10.0  # a median ESS at the last step below this: warn that the mixture is far from the limit


def _chunk_terms(bank: LinearSystems, y: Tensor, u: Tensor | None, steps: int) -> tuple[Tensor, Tensor]:
    """For the M systems of bank and N trajectories y (N, T+1, m), u (N, T+1, k)|None: each system's
    forecasts f (M, N, T+1, K, m), f[..., t, j] its Kalman prediction of y_{t+j} from y_{<t} (and the inputs
    up to u_{t+j-1}; zero past T), and the log-likelihood of the outputs before t, log p(y_{<t}) (M, N, T+1).
    """
    T1, m = y.shape[1], y.shape[2]
    K, S_inv, logdet = predictor_gains(bank, T1 - 1)
    x, e = filter_means(bank, y[None], None if u is None else u[None], K)  # (M, N, T+1, n), (.., m)
    quad = torch.einsum("mnti,mtij,mntj->mnt", e, S_inv, e)  # (M, N, T+1)
    logp = -0.5 * (quad + logdet[:, None] + m * math.log(2 * math.pi))  # log N(y_t; yhat_t, S_t)
    loglik = torch.cat([logp.new_zeros(logp.shape[:2] + (1,)), logp[..., :-1].cumsum(-1)], -1)  # y_{<t}
    out = [x @ bank.C[:, None].mT]
    for j in range(1, steps):  # the time update with no measurement: x <- A x + B u_{t+j-1}
        x = x @ bank.A[:, None].mT
        if bank.B is not None and u is not None:
            ahead = torch.zeros_like(u)
            ahead[:, : T1 - j + 1] = u[:, j - 1 :]  # origin t reads u_{t+j-1}
            x = x + ahead[None] @ bank.B[:, None].mT
        out.append(x @ bank.C[:, None].mT)
    return torch.stack(out, 3), loglik


@dataclasses.dataclass(frozen=True)
class BankSums:
    """What a bank's mixture needs of its systems, over N trajectories: lse = log sum_j p_j(y_{<t}) and
    lse2 = log sum_j p_j(y_{<t})^2 (N, T+1), and mean the weighted mean of their forecasts (N, T+1, K, m).
    Two banks' sums combine (`+`) into those of their union, so a bank can be split into chunks, or into
    shards run in separate processes (scripts/bayes_bank.py), with the same result up to float rounding."""

    lse: Tensor
    lse2: Tensor
    mean: Tensor

    def __add__(self, other: BankSums) -> BankSums:
        total = torch.logaddexp(self.lse, other.lse)
        mean = (self.lse - total).exp()[..., None, None] * self.mean
        mean = mean + (other.lse - total).exp()[..., None, None] * other.mean
        return BankSums(total, torch.logaddexp(self.lse2, other.lse2), mean)

    @property
    def ess(self) -> Tensor:
        """(N, T+1): the weights' effective sample size 1 / sum_j w_j^2."""
        return (2 * self.lse - self.lse2).exp()


def bank_sums(bank: LinearSystems, y: Tensor, u: Tensor | None, chunk: int = 512, steps: int = 1) -> BankSums:
    """The BankSums of `bank` over y (N, T+1, m) complete and u (N, T+1, k) or None, float64, processed in
    chunks of `chunk` systems (memory O(chunk N T K m))."""
    if torch.isnan(y).any():
        raise MopError("bayes: the outputs have gaps (NaN); the Bayes mixture needs complete outputs")
    y = y.double()
    u = None if u is None else u.double()
    sums = None
    for lo in range(0, bank.A.shape[0], chunk):
        preds, loglik = _chunk_terms(bank[lo : lo + chunk], y, u, steps)
        weights = torch.softmax(loglik, 0)[..., None, None]
        part = BankSums(torch.logsumexp(loglik, 0), torch.logsumexp(2 * loglik, 0), (weights * preds).sum(0))
        sums = part if sums is None else sums + part
    return sums


def bayes_mixture(
    bank: LinearSystems, y: Tensor, u: Tensor | None, chunk: int = 512, steps: int = 1
) -> tuple[Tensor, Tensor]:
    """(f (N, T+1, K, m), ess (N, T+1)), K = steps: the likelihood-weighted mean of the bank's Kalman
    forecasts, f[:, t, j] of y_{t+j} from y_{<t} (and the inputs up to u_{t+j-1}; j = 0 the one-step
    prediction; the module docstring), weighted by p(y_{<t}), and the weights' effective sample size, for y
    (N, T+1, m) complete, u (N, T+1, k) or None. The bank is processed in chunks of `chunk` systems (memory
    O(chunk N T K m)); the result does not depend on the chunking up to float rounding."""
    sums = bank_sums(bank, y, u, chunk, steps)
    return sums.mean, sums.ess


def draw_bank(system: SystemConfig, size: int, seed: int, horizon: int = 0) -> LinearSystems:
    """`size` systems of the family `system` (its sampler, seed + BANK_SEED_OFFSET), checked linear and
    time-invariant over t = 0..horizon (mop.filters.linear_gaussian.family_systems)."""
    family = make_family(system, dtype=torch.float64)
    params = family.sample(size, generator=generator(seed + BANK_SEED_OFFSET))
    return family_systems(family, params, horizon)


@PREDICTORS.register("bayes", skip_presets=("smoke", "small"), needs_family=True)
class BayesPredictor:
    """The Bayes predictor over the test systems' family (bayes_mixture over `bank_size` systems drawn from
    it): the best any predictor that knows the family but not the system can do, up to the bank's size.
    `system` is the family's config (an experiment passes its test family's)."""

    name = "bayes"

    def __init__(self, system: SystemConfig | None = None, bank_size: int = 20_000, seed: int = 0) -> None:
        if system is None:
            raise MopError("bayes: needs the family the systems come from (system=SystemConfig)")
        self.system, self.bank_size, self.seed = system, bank_size, seed
        self.ess: Tensor | None = None

    def predict(self, traj: Trajectories) -> Tensor:
        return self.forecast(traj, 1)[:, :, 0]

    def forecast(self, traj: Trajectories, steps: int) -> Tensor:
        """(B, T+1, K, m): the mixture's k-step forecasts (bayes_mixture; entries past T are dropped by
        mop.predictors.forecast)."""
        bank = draw_bank(self.system, self.bank_size, self.seed, traj.horizon)
        f, self.ess = bayes_mixture(bank, traj.y, traj.u, chunk=max(1, 512 // steps), steps=steps)
        ess = float(self.ess[:, -1].median())
        if ess < LOW_ESS:
            warnings.warn(
                MopWarning(
                    f"bayes: the median effective sample size of its {self.bank_size} systems is {ess:.1f} "
                    f"at t = {traj.horizon}: few of the drawn systems explain the data (a narrow posterior, "
                    "or too many unknowns for sampling from the prior), so the mixture may be far from the "
                    "Bayes predictor (its error is only an upper bound of the Bayes error); a larger "
                    "bank_size moves it closer (scripts/bayes_bank.py EXPERIMENT grows it in shards until "
                    "the estimate settles)"
                ),
                stacklevel=2,
            )
        return f.to(traj.y.dtype)
