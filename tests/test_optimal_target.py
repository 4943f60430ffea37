"""train.target = "optimal": training targets are the Kalman filter's predictions of each training system;
the decomposition that makes it the same objective as the paper's, checked statistically."""

import pytest
import torch

from mop.config import RunConfig, SystemConfig, TrainConfig, from_dict
from mop.errors import MopError
from mop.filters.kalman import KalmanPredictor
from mop.predictors import make_predictor
from mop.systems import generator, make_family
from mop.train.data import TrainingData

SYSTEM = {"family": "linear-inputs", "state_dim": 3, "output_dim": 2, "input_dim": 1}


def _data(target: str, **train) -> TrainingData:
    cfg = {"system": SYSTEM, "train": {"num_source_systems": 0, "batch_size": 8, "horizon": 20, **train}}
    cfg["train"]["target"] = target
    return TrainingData(from_dict(RunConfig, cfg), torch.device("cpu"))


def test_targets_are_the_kalman_predictions_of_the_same_systems():
    plain, optimal = _data("outputs").batch(), _data("optimal").batch()
    torch.testing.assert_close(plain[0], optimal[0])  # the same systems and inputs: the KF draws nothing
    family = make_family(SystemConfig(**SYSTEM))
    traj = family.generate(8, 20, generator=torch.Generator().manual_seed(0))  # TrainingData's first draw
    torch.testing.assert_close(plain[1], traj.y[:, 1:].float())
    kalman = KalmanPredictor().predict(traj)[:, 1:].float()
    torch.testing.assert_close(optimal[1], kalman, atol=1e-5, rtol=1e-5)


def test_the_two_losses_differ_by_a_constant():
    """E||f - y_t||^2 = E||f - yhat_t||^2 + E||y_t - yhat_t||^2 for a predictor f of the past (here `last`):
    the cross term E[(f - yhat_t) . (y_t - yhat_t)] is zero (within 4 standard errors over 4000 systems),
    so both targets have the same minimiser."""
    family = make_family(SystemConfig(**SYSTEM), torch.float64)
    traj = family.generate(4000, 20, generator=generator(3))
    yhat = KalmanPredictor().predict(traj)
    f = make_predictor("last").predict(traj)
    cross = ((f - yhat) * (traj.y - yhat)).sum(-1)[:, 1:].mean(1)  # (N,) per system
    se = cross.std() / cross.numel() ** 0.5
    assert abs(float(cross.mean())) < 4 * float(se)
    # and the optimal target's loss varies less over systems: the innovation's noise is left out
    loss_y = ((f - traj.y) ** 2).sum(-1)[:, 1:].mean(1)
    loss_opt = ((f - yhat) ** 2).sum(-1)[:, 1:].mean(1)
    assert float(loss_opt.var()) < float(loss_y.var())


@pytest.mark.parametrize(
    ("overrides", "match"),
    [({"missing_rate": 0.1}, "dropped outputs"), ({"simulate_after": 5}, "dropped outputs")],
)
def test_optimal_target_refuses_dropped_outputs(overrides, match):
    with pytest.raises(MopError, match=match):
        TrainConfig(target="optimal", **overrides)


def test_optimal_target_refuses_a_family_without_a_linear_model():
    cfg = {"system": {"family": "cascaded-tanks"}, "train": {"num_source_systems": 0, "target": "optimal"}}
    with pytest.raises(MopError, match="not linear|constant term|no state-space"):
        TrainingData(from_dict(RunConfig, cfg), torch.device("cpu"))
