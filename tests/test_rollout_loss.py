"""The simulation loss by rollout (train.rollout_after, mop.train.rollout_loss): the free run it trains is
the free run the learned predictor simulates (inside the model's context, to float rounding), its gradient
reaches the weights through the fed-back predictions, and training on it lowers the free-run error."""

import numpy as np
import pytest
import torch

from mop.config import RunConfig, apply_overrides
from mop.errors import MopError
from mop.recipe.fit import fit_record
from mop.record import Record
from mop.runs import load_predictor
from mop.systems.base import Trajectories
from mop.train.records import TrainingRecords
from mop.train.rollout_loss import check_rollout, rollout_loss, rollout_predictions, rollout_start

pytestmark = pytest.mark.usefixtures("one_thread")


def plant(steps: int = 1200, seed: int = 0) -> Record:
    """y_t = 0.7 y_{t-1} + 0.6 tanh(2 u_{t-1}) + 0.02 e_t: a saturating first-order plant."""
    rng = np.random.default_rng(seed)
    u = rng.normal(size=steps)
    y = np.zeros(steps)
    for t in range(1, steps):
        y[t] = 0.7 * y[t - 1] + 0.6 * np.tanh(2 * u[t - 1]) + 0.02 * rng.normal()
    return Record(y=y, u=u, name="plant")


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A records run of 30 one-step steps: its network reads the fitted ARX feature and corrects it."""
    out = tmp_path_factory.mktemp("rollout") / "run"
    over = ["train.steps=30", "model.arch=gpt"]  # the transformer reading the feature
    fit_record(out, TrainingRecords((plant(),)), overrides=over, progress=False)
    return out


def test_the_trained_free_run_is_the_predictors_simulation(run):
    predictor = load_predictor(run)
    model, norm = predictor.model, predictor.normalization
    record = plant(41, seed=3)  # 40 steps: inside the model's context
    assert len(record.y) - 1 <= model.cfg.context
    traj = Trajectories(
        y=torch.tensor(record.y[None]), u=torch.tensor(record.u[None]), params=None, family=""
    )
    c = 7
    simulated = predictor.simulate(traj, c)  # (1, T + 1 - c, 1): y_c..y_T in the record's units
    inputs = predictor.inputs(traj)  # z_0..z_{T-1}, the model's units
    with torch.no_grad():
        trained = rollout_predictions(model, inputs, c, 1)  # y_c..y_T, the model's units
    back = norm.outputs(trained, None)[0]
    torch.testing.assert_close(back.double(), simulated.double(), rtol=1e-4, atol=1e-5)
    assert not torch.allclose(simulated[0, 1:], traj.y[0, c + 1 :].to(simulated.dtype), atol=1e-3)


def test_the_gradient_reaches_the_weights_through_the_fed_back_predictions(run):
    model = load_predictor(run).model
    model.train()
    inputs = torch.randn(2, 20, 2, dtype=next(model.parameters()).dtype)
    targets = torch.randn(2, 20, 1, dtype=inputs.dtype)
    fed = inputs.clone().requires_grad_(True)
    loss = rollout_loss(model, fed, targets, 5)
    loss.backward()
    # the outputs read after step 5 are the model's own: their measured values get no gradient
    assert fed.grad[:, 5:, 0].abs().max() == 0 and fed.grad[:, :5, 0].abs().max() > 0
    assert model.read_out.weight.grad.abs().max() > 0


def test_the_rollout_share_and_the_checks():
    config = apply_overrides(
        RunConfig(), ["train.steps=100", "train.rollout_after=5", "train.rollout_share=0.2"]
    )
    assert rollout_start(config) == 80
    assert rollout_start(apply_overrides(RunConfig(), ["train.steps=100"])) is None
    with pytest.raises(MopError, match="observation_mask"):
        check_rollout(apply_overrides(config, ["model.observation_mask=true"]))
    with pytest.raises(MopError, match="train.rollout_after"):
        apply_overrides(RunConfig(), ["train.horizon=10", "train.rollout_after=10"])
