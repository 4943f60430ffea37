"""Direct k-step heads (model.horizons = K, model.forecast_mode = "direct"): head k at position t predicts
y_{t+k} from z_0..z_t, trained by the mean of the heads' losses; LearnedPredictor.direct_forecast reads them
with the window semantics of predict. Checked against their definitions (one forward per origin), a loss
written out by hand, the closed-form k-step predictor of a scalar ARX(1, 1) process, which future inputs a
head reads, and one-line errors."""

import pytest
import torch

from mop.config import ModelConfig
from mop.errors import MopError
from mop.models import build_model
from mop.models.predict import stream
from mop.models.predictor import LearnedPredictor
from mop.systems.base import Trajectories
from tests.reference_models import half_window_start
from tests.test_rollout import CONTEXT, random_model, random_trajectories

pytestmark = pytest.mark.usefixtures("one_thread")

HEADS = 4


def direct_model(arch: str, position: str = "learned", inputs: int = 0) -> torch.nn.Module:
    model = random_model(arch, position, "mean", inputs, horizons=HEADS, forecast_mode="direct")
    if model.future_head is not None:
        with torch.no_grad():
            for p in model.future_head.parameters():  # an untrained F is zero; make every input matter
                p.normal_(0.0, 0.3)
    return model


def by_definition(model: torch.nn.Module, traj: Trajectories, steps: int, mode: str) -> torch.Tensor:
    """f[:, t, j] = head j+1 at the last input of one forward on the window of z_0..z_{t-1} that `mode` reads
    (its last C inputs, or from half_window_start), given the future inputs u_t..u_{t+K-2} (0 beyond u_T)."""
    z = traj.model_inputs()[:, :-1]
    B, T1, m = traj.y.shape
    out = traj.y.new_full((B, T1, steps, m), float("nan"))
    out[:, 0] = 0.0
    for t in range(1, T1):
        start = max(0, t - CONTEXT) if mode == "sliding" else half_window_start(t - 1, CONTEXT)
        start = start if model.context_limited else 0
        window = z[:, start:t]
        future = None
        if traj.u is not None:  # for each window position p: u_{p+1}..u_{p+K-1}
            u = torch.cat([traj.u, traj.u.new_zeros(B, HEADS, traj.u.shape[-1])], dim=1)
            p = range(start, t)
            future = torch.stack([torch.stack([u[:, q + 1 + i] for i in range(HEADS - 1)], 1) for q in p], 1)
        heads = model.forecast_heads(window, future=future)[:, -1]  # (B, K, m)
        for j in range(min(steps, T1 - t)):
            out[:, t, j] = heads[:, j]
    return out


@pytest.mark.parametrize("arch,position", [("gpt", "learned"), ("gpt", "rope"), ("gru", "learned")])
@pytest.mark.parametrize("horizon,steps", [(CONTEXT - 3, HEADS), (3 * CONTEXT + 2, 3)])
@pytest.mark.parametrize("inputs", [0, 2])
@pytest.mark.parametrize("mode", ["window", "sliding"])
def test_direct_forecast_equals_one_forward_per_origin(arch, position, horizon, steps, inputs, mode):
    model = direct_model(arch, position, inputs)
    p = LearnedPredictor(model, mode=mode, chunk_size=2)  # several chunks of systems
    traj = random_trajectories(5, horizon, inputs)
    fast = p.forecast(traj, steps)
    with torch.no_grad():
        slow = by_definition(model, traj, steps, mode)
    assert torch.equal(fast.isnan(), slow.isnan())
    torch.testing.assert_close(fast, slow, rtol=0, atol=1e-10, equal_nan=True)
    torch.testing.assert_close(fast[:, :, 0], p.predict(traj), rtol=0, atol=1e-10)  # head 1 is predict


@pytest.mark.parametrize("arch", ["gpt", "gru", "deep-lru"])
def test_one_step_head_streams_like_the_forward(arch):
    model = direct_model(arch, "rope")
    z = random_trajectories(3, CONTEXT - 1, 0).model_inputs()[:, :-1]
    with torch.no_grad():
        torch.testing.assert_close(stream(model, z)[0], model(z), rtol=0, atol=1e-10)
        torch.testing.assert_close(model.forecast_heads(z)[:, :, 0], model(z), rtol=0, atol=0)


@pytest.mark.parametrize("arch", ["gpt", "gru", "deep-lru"])
@pytest.mark.parametrize("horizon", [CONTEXT, 2])  # 2 < K: only the heads with a target count
def test_loss_is_the_mean_of_the_heads_mse(arch, horizon):
    model = direct_model(arch)
    traj = random_trajectories(4, horizon, 0)
    z, targets = traj.model_inputs()[:, :-1], traj.y[:, 1:]
    heads = model.forecast_heads(z)  # (B, T, K, m)
    T = targets.shape[1]
    terms = [((heads[:, : T - k, k] - targets[:, k:]) ** 2).mean() for k in range(min(HEADS, T))]
    torch.testing.assert_close(model.loss(z, targets), sum(terms) / len(terms), rtol=1e-12, atol=0)


def test_balanced_loss_keeps_the_value_and_scales_each_heads_gradient():
    """horizon_loss 'balanced': the value is the mean of the heads' losses L_k, the gradient is
    mean(L) / K * sum_k grad(L_k) / L_k (each written out by autograd on its own)."""
    model = random_model("gpt", "learned", "mean", 0, horizons=HEADS, horizon_loss="balanced")
    traj = random_trajectories(4, CONTEXT, 0)
    z, targets = traj.model_inputs()[:, :-1], traj.y[:, 1:]
    params = list(model.parameters())
    grads = torch.autograd.grad(model.loss(z, targets), params)
    heads = model.forecast_heads(z)
    T = targets.shape[1]
    losses = [((heads[:, : T - k, k] - targets[:, k:]) ** 2).mean() for k in range(HEADS)]
    level = float(sum(losses).detach() / HEADS)
    torch.testing.assert_close(model.loss(z, targets).detach(), torch.tensor(level, dtype=torch.float64))
    want = [torch.zeros_like(p) for p in params]
    for L in losses:
        for w, g in zip(want, torch.autograd.grad(L, params, retain_graph=True), strict=True):
            w += level / HEADS * g / float(L.detach())
    for g, w in zip(grads, want, strict=True):
        torch.testing.assert_close(g, w, rtol=1e-5, atol=1e-9)  # the read-out is float32


@pytest.mark.parametrize("inputs", [0, 1])
def test_heads_learn_the_k_step_predictor_of_an_arx_process(inputs):
    """y_{t+1} = a y_t + b u_t + 0.1 e_t with white u (b = 0 without inputs), y_0 ~ N(0, 1): the MSE-optimal
    prediction of y_{t+k} from y_t, u_t and the known u_{t+1}..u_{t+k-1} is
    a^k y_t + sum_{i<k} a^(k-1-i) b u_{t+i}. After training, head k's least-squares coefficients on
    [y_t, u_t, .., u_{t+k-1}] are within 0.05 of those, and its coefficient on y_t is nearer a^k than
    a^(k-1) or a^(k+1), so each head predicts its own horizon from the inputs it may read."""
    a, b, T = 0.6, 0.5 * inputs, 24
    torch.manual_seed(0)
    cfg = ModelConfig(
        arch="gru",
        num_layers=1,
        num_heads=1,
        width=32,
        context=T,
        input_dim=1 + inputs,
        output_dim=1,
        horizons=HEADS,
        forecast_mode="direct",
    )
    model = build_model(cfg)
    opt = torch.optim.Adam(model.parameters(), lr=1e-2)

    def arx(n: int) -> tuple[torch.Tensor, torch.Tensor]:
        y, u = torch.zeros(n, T + 1, 1), torch.randn(n, T + 1, 1)
        y[:, 0] = torch.randn(n, 1)
        for t in range(T):
            y[:, t + 1] = a * y[:, t] + b * u[:, t] + 0.1 * torch.randn(n, 1)
        return y, u

    def model_inputs(y: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        return torch.cat([y, u], dim=-1)[:, :-1] if inputs else y[:, :-1]

    for _ in range(200):
        y, u = arx(64)
        opt.zero_grad()
        model.loss(model_inputs(y, u), y[:, 1:]).backward()
        opt.step()
    y, u = arx(500)
    with torch.no_grad():
        heads = model.forecast_heads(model_inputs(y, u))[..., 0]  # (N, T, K)
    for k in range(1, HEADS + 1):
        t = torch.arange(T - k + 1)  # positions whose y_{t+k} exists
        columns = [y[:, t, 0]] + [u[:, t + i, 0] for i in range(k)] * inputs  # y_t, u_t..u_{t+k-1}
        X = torch.stack(columns, dim=-1).reshape(-1, len(columns))
        coef = torch.linalg.lstsq(X, heads[:, t, k - 1].reshape(-1, 1)).solution[:, 0]
        want = torch.tensor([a**k] + [a ** (k - 1 - i) * b for i in range(k)] * inputs)
        torch.testing.assert_close(coef, want, rtol=0, atol=0.05)
        assert abs(coef[0] - a**k) < min(abs(coef[0] - a ** (k - 1)), abs(coef[0] - a ** (k + 1))), (k, coef)


def test_a_head_reads_only_the_future_inputs_before_its_target():
    """Head k at position t reads u_{t+1}..u_{t+k-1}: changing u_{t+k} leaves it, changing u_{t+k-1} moves it
    (k >= 2); on the sliding-window path too (T > C)."""
    model = random_model("gpt", "learned", "mean", 2, horizons=HEADS, forecast_mode="direct")
    with torch.no_grad():
        for p in model.future_head.parameters():  # an untrained F is zero; make every input matter
            p.normal_(0.0, 0.3)
    predictor = LearnedPredictor(model)
    traj = random_trajectories(2, 3 * CONTEXT, 2)
    base = predictor.forecast(traj, HEADS)
    t, k = 2 * CONTEXT, 3  # origin t: head k forecasts y_{t+k-1} from z_0..z_{t-1} and u_t..u_{t+k-2}
    for moved, changes in ((t + k - 1, False), (t + k - 2, True)):
        u = traj.u.clone()
        u[:, moved] += 1.0
        f = predictor.forecast(Trajectories(traj.y, u), HEADS)
        assert bool((f[:, t, k - 1] - base[:, t, k - 1]).abs().max() > 1e-6) == changes, moved


def test_direct_errors_are_one_line():
    with pytest.raises(MopError, match="set model.horizons"):
        ModelConfig(forecast_mode="direct")
    with pytest.raises(MopError, match="model.horizons must be"):
        ModelConfig(horizons=0)
    with pytest.raises(MopError, match="use model.readout='mean'"):
        ModelConfig(horizons=3, horizon_loss="balanced", readout="gaussian")
    p = LearnedPredictor(direct_model("gpt"))
    with pytest.raises(MopError, match=f"at most {HEADS} steps, not {HEADS + 1}"):
        p.forecast(random_trajectories(2, 10, 0), HEADS + 1)
