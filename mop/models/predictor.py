"""The trained model as a Predictor (mop.predictors): one-step predictions, k-step forecasts, simulation.

    p = LearnedPredictor(model, mode="window")     # model: mop.models.build_model(cfg)
    p.predict(traj)             # (B, T+1, m)     yhat[:, t] from z_0..z_{t-1}       mop.models.predict
    p.predict_distribution(traj)  # mean, var (B, T+1, m) of a Gaussian read-out     mop.models.predict
    p.forecast(traj, K)         # (B, T+1, K, m)  f[:, t, j] forecasts y_{t+j}       mop.models.forecast
    p.simulate(traj, c)         # (B, T+1-c, m)   free run from y_0..y_{c-1}         mop.models.simulate

Each job lives in its own module with one chooser of its path (by `mode`, model.forecast_mode and the
model's declared capabilities, mop.models.interface); inputs of a recorded-data run are normalised and
inputs far outside the training data flagged (mop.models.normalization).
"""

from __future__ import annotations

from torch import Tensor

from mop.models import forecast as forecasts
from mop.models import simulate as simulations
from mop.models.normalization import Normalization
from mop.models.predict import ModelPredictor
from mop.systems.base import Trajectories

__all__ = ["LearnedPredictor", "Normalization"]


class LearnedPredictor(ModelPredictor):
    """Predictor protocol around a model of mop.models.build_model (run in eval mode, no grad, in chunks)."""

    def forecast(self, traj: Trajectories, steps: int) -> Tensor:
        """(B, T+1, K, m) k-step forecasts, K = steps: f[:, t, j] forecasts y_{t+j} from z_0..z_{t-1}
        (and the given inputs u_t..u_{t+j-1}); j = 0 is predict(traj); NaN where t + j > T.
        How (fed back, heads, or gaps): mop.models.forecast."""
        return forecasts.forecast(self, traj, steps)

    def simulate(self, traj: Trajectories, context: int) -> Tensor:
        """(B, T+1-c, m) free-run simulation, c = context: forecast[:, c] alone (the model reads z_0..z_{c-1},
        then its own predicted outputs with the given inputs); mop.models.simulate."""
        return simulations.simulate(self, traj, context)
