"""Training with an estimation record as context (train.context_prefix, mop.train.context): each training
window is exactly a window of the in-context "fit" reading (mop.incontext.fitted_to_context), whose
estimation record is the window's prefix; bad settings are one line before any work."""

import copy
import dataclasses

import numpy as np
import pytest
import torch

import mop.train as mt
from mop.checkpoint import load_tensors
from mop.config import DataConfig, RunConfig
from mop.errors import MopError
from mop.incontext import context_normalization, fits_context, fitted_to_context, readings
from mop.missing import masked_inputs
from mop.models.registry import build_model
from mop.recipe.finetune import with_fine_tuning
from mop.record import Record
from mop.runs import load_config, load_predictor
from mop.systems import generator, make_family
from mop.train import TrainingData, validation_batch
from mop.train.context import check_context_prefix, prefix_fit
from tests.reference import interrupted_and_resumed

pytestmark = pytest.mark.usefixtures("one_thread")

PREFIX, BODY = 400, 120


@pytest.fixture(scope="module")
def lti():
    """pretrained:lti-siso and 4 systems of its class, PREFIX + BODY steps each."""
    config = load_config("pretrained:lti-siso")
    traj = make_family(config.system).generate(4, PREFIX + BODY - 1, generator=generator(5))
    return load_predictor("pretrained:lti-siso"), traj.model_inputs().double()  # (4, PREFIX + BODY, 2)


def test_the_prefix_fit_is_the_in_context_least_squares_fit_of_each_estimation_record(lti):
    predictor, z = lti
    body, theta = prefix_fit(z, PREFIX, predictor.cfg)
    assert body.shape == (4, BODY, 2) and theta.shape[0] == 4
    for b in range(4):
        context = Record(y=z[b, :PREFIX, :1].numpy(), u=z[b, :PREFIX, 1:].numpy())
        fitted = fitted_to_context(predictor, [context])
        expected = np.asarray(fitted.cfg.rls_prior).reshape(theta.shape[1:])
        np.testing.assert_allclose(theta[b].numpy(), expected, rtol=1e-7, atol=1e-9)
        norm = context_normalization([context])
        units = norm.inputs(z[b : b + 1, PREFIX:])[0]
        np.testing.assert_allclose(body[b].numpy(), units.numpy(), rtol=1e-12, atol=1e-12)


def test_a_training_window_is_a_window_of_the_fit_reading(lti):
    """The network's predictions with each record's coefficients (training) equal those of the class model
    fitted to that record's prefix (in context), the free run's missing outputs included."""
    predictor, z = lti
    body, theta = prefix_fit(z, PREFIX, predictor.cfg)
    y = body[..., :1].clone()
    y[:, 60:] = float("nan")  # a free run from step 60: the feature fills the outputs in
    inputs = masked_inputs(torch.cat([y, body[..., 1:]], dim=-1), 1).float()
    model = predictor.model
    with torch.no_grad():
        trained = model._outputs(inputs, fitted=theta)[0]
        for b in range(4):
            context = Record(y=z[b, :PREFIX, :1].numpy(), u=z[b, :PREFIX, 1:].numpy())
            in_context = fitted_to_context(predictor, [context]).model(inputs[b : b + 1])
            np.testing.assert_allclose(trained[b].numpy(), in_context[0].numpy(), rtol=1e-4, atol=1e-5)
    assert torch.isfinite(trained).all()


def test_without_record_norm_a_window_is_the_records_recipes_window_of_its_estimation_record(lti):
    """A network of the records recipe's shape (no record_norm: it reads a record in the record's global
    units) given each system's prefix coefficients in training predicts as the same network built with those
    coefficients as its listed model.rls_prior (the fine-tune's start on a record) reads the window in the
    prefix's units: the feature's prior is each record's fit, P_0 as a listed prior's."""
    predictor, z = lti
    cfg = dataclasses.replace(
        predictor.cfg,
        record_norm="none",
        residual_scale="none",
        observation_mask=False,
        forecast_mode="rollout",
        input_dim=2,
        num_layers=1,
        width=32,
        num_heads=2,
        context=BODY,
    )
    body, theta = prefix_fit(z, PREFIX, cfg)
    torch.manual_seed(0)
    model = build_model(cfg).eval()
    inputs = body.float()
    with torch.no_grad():
        trained = model._outputs(inputs, fitted=theta)[0]
        for b in range(4):
            listed = dataclasses.replace(cfg, rls_prior=theta[b].flatten().tolist(), rls_p0=1.0)
            one = build_model(listed).eval()
            one.load_state_dict(model.state_dict())
            alone = one._outputs(inputs[b : b + 1])[0]
            np.testing.assert_allclose(trained[b].numpy(), alone[0].numpy(), rtol=1e-5, atol=1e-6)
        # the feature is the prefix's fit, not one identified in the window: without the coefficients the
        # predictions differ
        plain = model._outputs(inputs)[0]
    assert (plain - trained).abs().max() > 1e-3


def _config(**train) -> RunConfig:
    source = load_config("pretrained:lti-siso")
    keys = {"steps": 2, "batch_size": 3, "horizon": 99, "simulate_after": 40, "num_source_systems": 0}
    model = dataclasses.replace(source.model, context=100)
    return dataclasses.replace(
        source, model=model, train=dataclasses.replace(source.train, **{**keys, **train})
    )


def test_batches_hold_each_systems_coefficients_and_are_seeded():
    config = _config(context_prefix=300)
    first, second = (TrainingData(config, torch.device("cpu")).batch() for _ in range(2))
    inputs, targets, fitted = first
    assert inputs.shape == (3, 99, 3) and targets.shape == (3, 99, 1)
    assert fitted.shape == (3, 31, 1) and fitted.dtype == torch.float64
    for a, b in zip(first, second, strict=True):
        torch.testing.assert_close(a, b, equal_nan=True)
    val = validation_batch(config, torch.device("cpu"))
    assert len(val) == 3 and val[2].shape[0] == val[0].shape[0]


def test_a_share_of_the_batches_reads_the_estimation_record_the_rest_their_windows_alone():
    """train.context_prefix_share = 0.5: over 40 seeded batches the share carrying coefficients is within
    the binomial's 3-sigma band of 20 (+-9.5), the same seed draws the same kinds, and a batch without
    coefficients runs through the loss as a record without an estimation record."""
    config = _config(context_prefix=300, context_prefix_share=0.5, batch_size=2)
    kinds = []
    for _ in range(2):
        data = TrainingData(config, torch.device("cpu"))
        kinds.append([len(data.batch()) == 3 for _ in range(40)])
    assert kinds[0] == kinds[1] and 11 <= sum(kinds[0]) <= 29
    data = TrainingData(config, torch.device("cpu"))
    plain = next(b for b in iter(data.batch, None) if len(b) == 2)
    model = build_model(dataclasses.replace(config.model, input_dim=3, output_dim=1))
    assert torch.isfinite(model.loss(*plain))


@pytest.mark.parametrize(
    "change, message",
    [
        ({"context_prefix": 30}, "cannot fit the feature.s 31 coefficients"),
        ({"context_prefix": -1}, "train.context_prefix"),
        ({"context_prefix": 300, "context_prefix_share": 0.0}, "train.context_prefix_share"),
        ({"context_prefix": 300, "target": "optimal", "simulate_after": 0}, "use train.target=outputs"),
    ],
)
def test_a_prefix_that_cannot_serve_is_one_line(change, message):
    with pytest.raises(MopError, match=message):
        check_context_prefix(_config(**change))


def test_a_prefix_needs_a_feature_of_its_own_fit_and_a_simulated_family():
    config = _config(context_prefix=300)
    listed = dataclasses.replace(
        config, model=dataclasses.replace(config.model, rls_prior=[0.0] * 31, rls_p0=1.0)
    )
    with pytest.raises(MopError, match="no model.rls_prior"):
        check_context_prefix(listed)
    recorded = dataclasses.replace(config, data=DataConfig(path="x.npz"))
    with pytest.raises(MopError, match="recorded file has its own"):
        check_context_prefix(recorded)


def test_same_seed_same_weights_and_resume_equals_uninterrupted(tmp_path, monkeypatch):
    """A class model trained with estimation prefixes: the batches' coefficients travel with the seeded
    generator, so a run stopped and resumed ends with the weights of one that was not."""
    config = _config(context_prefix=150, steps=6, checkpoint_every=2, keep_best=False)
    config = dataclasses.replace(config, model=dataclasses.replace(config.model, width=8, num_layers=1))
    a = mt.train(config, tmp_path / "a", progress=False)
    c = interrupted_and_resumed(config, tmp_path / "c", monkeypatch)
    wa, wc = (load_tensors(run / "model.safetensors")[0] for run in (a, c))
    assert all(torch.equal(wa[k], wc[k]) for k in wa)
    torch.manual_seed(config.train.seed)
    start = build_model(config.model).state_dict()
    assert any(not torch.equal(wa[k], start[k]) for k in wa)  # it did train


def test_a_fine_tune_of_a_model_trained_with_prefixes_reads_its_record_as_the_estimation_record():
    source = _config(context_prefix=300)
    run = dataclasses.replace(source, data=DataConfig(path="est.csv"))
    tuned = with_fine_tuning(run, source, "pretrained:x")
    assert tuned.train.context_prefix == 0 and tuned.train.init == "pretrained:x"
    check_context_prefix(tuned)  # no refusal: the record's own feature fit serves (with_record_prior)


def test_a_records_start_reads_an_estimation_record_in_context_as_it_trained():
    """pretrained:duffing-records (no record_norm, trained with estimation prefixes) gets the "fit" reading:
    fitted to a context it predicts a window read in the context's units exactly as in training, with that
    context as the window's prefix (its 80-step context, ARX(40, 40) fitted on 400 steps). A model of the
    same shape trained without prefixes gets no such reading."""
    predictor = load_predictor("pretrained:duffing-records")
    assert fits_context(predictor) and "fit gain 1" in readings(predictor)
    config = load_config("pretrained:duffing-records")
    traj = make_family(config.system).generate(3, PREFIX + 80 - 1, generator=generator(5))
    z = traj.model_inputs().double()
    body, theta = prefix_fit(z, PREFIX, predictor.cfg)
    inputs = body.float()
    with torch.no_grad():
        trained = predictor.model._outputs(inputs, fitted=theta)[0]
        for b in range(3):
            context = Record(y=z[b, :PREFIX, :1].numpy(), u=z[b, :PREFIX, 1:].numpy())
            in_context = fitted_to_context(predictor, [context]).model(inputs[b : b + 1])
            np.testing.assert_allclose(trained[b].numpy(), in_context[0].numpy(), rtol=1e-4, atol=1e-5)
    plain = copy.copy(predictor)
    plain.source = ""  # no run to say how it trained
    assert not fits_context(plain)


def test_without_a_feature_the_prefix_gives_the_windows_units_alone(lti):
    """A network without a feature (model.rls_order = 0: the records recipe's deep LRU) pretrained with a
    prefix reads each window in its estimation record's units, each channel's mean and std over the
    prefix (computed here by numpy), and gets no coefficients."""
    predictor, z = lti
    cfg = dataclasses.replace(
        predictor.cfg, rls_order=0, arx_order=0, rls_offset=False, residual_scale="none"
    )
    body, theta = prefix_fit(z, PREFIX, cfg)
    head = z[:, :PREFIX].numpy()
    expected = (z[:, PREFIX:].numpy() - head.mean(1, keepdims=True)) / head.std(1, keepdims=True)
    assert theta is None
    np.testing.assert_allclose(body.numpy(), expected, rtol=1e-12, atol=1e-12)
    config = _config(context_prefix=300)
    config = dataclasses.replace(
        config,
        model=dataclasses.replace(
            config.model, **{"rls_order": 0, "arx_order": 0, "rls_offset": False, "residual_scale": "none"}
        ),
    )
    check_context_prefix(config)  # no feature: nothing to fit, nothing refused
    inputs, targets = TrainingData(config, torch.device("cpu")).batch()
    assert inputs.shape[:2] == targets.shape[:2] == (3, 99)
